"""The generated C codec: up to date, warning-free, and bit-exact with the golden vectors.

The C test program is generated here from golden.json: for every vector it unpacks the
bytes and compares each raw struct member, packs the raw members and compares the bytes,
and checks the generated *_decode/*_encode/*_is_in_range helpers and the checksum helper.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from cantools.database.can.c_source import camel_to_snake_case

import alacs_can

CAN_PROTOCOL_DIR = Path(__file__).resolve().parents[2]
GENERATED = CAN_PROTOCOL_DIR / "generated"
HELPERS = CAN_PROTOCOL_DIR / "c"
STRICT = ["-std=c11", "-Wall", "-Wextra", "-Werror", "-Wconversion", "-Wsign-conversion",
          "-Wdouble-promotion", "-Wswitch-enum", "-Wpedantic", "-Wshadow"]

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not installed")


def _run(cmd: list[str], **kw: Any) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, capture_output=True, text=True, check=False, **kw)


def test_generate_check_passes() -> None:
    env = dict(os.environ, PYTHON=sys.executable)
    proc = _run(["bash", str(CAN_PROTOCOL_DIR / "generate.sh"), "--check"], env=env)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_generate_check_detects_drift(tmp_path: Path) -> None:
    # Copy the folder, corrupt one generated file, and expect --check to fail with a diff.
    copy = tmp_path / "can_protocol"
    shutil.copytree(CAN_PROTOCOL_DIR, copy, ignore=shutil.ignore_patterns("python"))
    header = copy / "generated" / "alacs.h"
    header.write_text(header.read_text().replace("(0x210u)", "(0x211u)", 1))
    env = dict(os.environ, PYTHON=sys.executable)
    proc = _run(["bash", str(copy / "generate.sh"), "--check"], env=env)
    assert proc.returncode != 0
    assert "+#define ALACS_ALACS_COMMAND_FRAME_ID (0x210u)" in proc.stdout


@needs_gcc
@pytest.mark.parametrize("std", ["-std=c11", "-std=c99"])
def test_generated_c_compiles_warning_free(tmp_path: Path, std: str) -> None:
    flags = [f for f in STRICT if not f.startswith("-std")] + [std]
    proc = _run(["gcc", *flags, "-c", str(GENERATED / "alacs.c"), "-o", str(tmp_path / "a.o")])
    assert proc.returncode == 0, proc.stderr


@needs_gcc
def test_headers_compile_as_cpp(tmp_path: Path) -> None:
    if shutil.which("g++") is None:
        pytest.skip("g++ not installed")
    src = tmp_path / "t.cpp"
    src.write_text('#include "alacs.h"\n#include "alacs_protocol.h"\n'
                   "int main() {\n"
                   "  const unsigned char d[9] = {'1','2','3','4','5','6','7','8','9'};\n"
                   "  return alacs_crc8_j1850(d, sizeof d) == 0x4B ? 0 : 1; }\n")
    proc = _run(["g++", "-std=c++17", "-Wall", "-Wextra", "-Werror", "-Wconversion",
                 "-Wsign-conversion", f"-I{GENERATED}", f"-I{HELPERS}", str(src),
                 "-o", str(tmp_path / "t")])
    assert proc.returncode == 0, proc.stderr
    assert _run([str(tmp_path / "t")]).returncode == 0


def test_protocol_header_matches_python() -> None:
    text = (HELPERS / "alacs_protocol.h").read_text()
    pattern = r"#define (ALACS_\w+) \((0x[0-9A-F]+|\d+)u\)"
    defines = {m[1]: int(m[2], 0) for m in re.finditer(pattern, text)}
    assert defines["ALACS_PROTOCOL_VERSION"] == alacs_can.PROTOCOL_VERSION
    assert defines["ALACS_DEFAULT_NODE_ID"] == alacs_can.DEFAULT_NODE_ID
    for name, base in alacs_can.BASE_IDS.items():
        key = {"ALACS_ResultHeader": "RESULT_HEADER", "ALACS_ResultObject": "RESULT_OBJECT"}.get(
            name, name.removeprefix("ALACS_").upper())
        assert defines[f"ALACS_BASE_ID_{key}"] == base, name


def _lit(value: int) -> str:
    return f"({value})" if value < 0 else f"{value}u"


def _bytes(data: bytes) -> str:
    return "{" + ", ".join(f"0x{b:02X}u" for b in data) + "}"


def _c_test_source(doc: dict[str, Any]) -> str:
    lines = [
        "#include <math.h>", "#include <stdio.h>", "#include <string.h>",
        '#include "alacs.h"', '#include "alacs_protocol.h"',
        "static int failures = 0;",
        "#define CHECK(cond, what) do { if (!(cond)) { ++failures; "
        'printf("FAIL %s: %s\\n", what, #cond); } } while (0)',
    ]
    for name, base in alacs_can.BASE_IDS.items():
        if name == "NMT":
            continue
        snake = camel_to_snake_case(name).upper()
        lines.append(f"_Static_assert({base}u + ALACS_DEFAULT_NODE_ID == ALACS_{snake}_FRAME_ID, "
                     f'"{name} id");')
    lines.append("int main(void) {")
    lines.append('  { const uint8_t d[] = "123456789"; '
                 'CHECK(alacs_crc8_j1850(d, 9) == 0x4Bu, "crc known answer"); }')
    for v in doc["vectors"]:
        msg = camel_to_snake_case(v["message"])
        fn = f"alacs_{msg}"
        data = bytes.fromhex(v["data"])
        what = v["name"]
        lines.append(f"  {{ /* {what} */")
        lines.append(f"    const uint8_t data[{len(data)}] = {_bytes(data)};")
        lines.append(f"    struct {fn}_t m; memset(&m, 0xA5, sizeof m);")
        lines.append(f'    CHECK({fn}_unpack(&m, data, sizeof data) == 0, "{what} unpack");')
        lines.append(f"    struct {fn}_t p; memset(&p, 0, sizeof p);")
        for sig, e in v["signals"].items():
            field = camel_to_snake_case(sig)
            raw = e["raw"]
            lines.append(f'    CHECK(m.{field} == {_lit(raw)}, "{what} {sig} raw");')
            lines.append(f"    p.{field} = {_lit(raw)};")
            phys = repr(e["physical"])
            lines.append(f"    CHECK(fabs({fn}_{field}_decode(m.{field}) - ({phys})) < 1e-6, "
                         f'"{what} {sig} decode");')
            lines.append(f"    CHECK({fn}_{field}_encode({phys}) == {_lit(raw)}, "
                         f'"{what} {sig} encode");')
            lines.append(f'    CHECK({fn}_{field}_is_in_range(m.{field}), "{what} {sig} range");')
        lines.append("    uint8_t out[8]; memset(out, 0xEE, sizeof out);")
        lines.append(f"    CHECK({fn}_pack(out, &p, sizeof out) == {len(data)}, "
                     f'"{what} pack len");')
        lines.append(f'    CHECK(memcmp(out, data, sizeof data) == 0, "{what} pack bytes");')
        if v["message"] == "ALACS_Command":
            lines.append(f'    CHECK(alacs_command_checksum_ok(data, sizeof data), "{what} crc");')
        lines.append("  }")
    for chk in doc["command_checks"]:
        data = bytes.fromhex(chk["data"]) or b"\x00"
        expect = "true" if chk["checksum_ok"] else "false"
        lines.append(f"  {{ const uint8_t d[{len(data)}] = {_bytes(data)};")
        lines.append(f"    CHECK(alacs_command_checksum_ok(d, {chk['dlc']}u) == {expect}, "
                     f'"check {chk["name"]}"); }}')
    count = len(doc["vectors"])
    lines.append(f'  printf("%d vectors, %d failures\\n", {count}, failures);')
    lines.append("  return failures == 0 ? 0 : 1;")
    lines.append("}")
    return "\n".join(lines) + "\n"


@needs_gcc
def test_generated_c_matches_golden_vectors(tmp_path: Path) -> None:
    doc = json.loads((CAN_PROTOCOL_DIR / "vectors" / "golden.json").read_text())
    src = tmp_path / "golden_test.c"
    src.write_text(_c_test_source(doc))
    exe = tmp_path / "golden_test"
    proc = _run(["gcc", *STRICT, "-Wno-pedantic", f"-I{GENERATED}", f"-I{HELPERS}", str(src),
                 str(GENERATED / "alacs.c"), "-lm", "-o", str(exe)])
    assert proc.returncode == 0, proc.stderr[:4000]
    run = _run([str(exe)])
    assert run.returncode == 0, run.stdout[:4000]
    assert f"{len(doc['vectors'])} vectors, 0 failures" in run.stdout
