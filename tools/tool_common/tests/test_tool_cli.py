"""The C++ tools' command lines (CLI11 through tools/tool_common/cli.h): --help exits 0
with the help on stdout; an unknown option or a bad value exits 2 with one line on stderr.

The tools are taken from $ALACS_TOOLS_BUILD (a CMake build directory), else from the
newest build/*/ that holds them; a tool that is not built there is skipped.
"""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]

# (binary under the build's tools/, subcommand words, a command line with a bad value)
TOOLS = [
    ("lle/alacs_lle", [], ["img.png", "--step", "four"]),
    ("lle/alacs_lle", [], ["img.png", "--method", "magic"]),
    ("lle/alacs_lle", [], ["img.png", "--roi", "1,2,3"]),
    ("lle/alacs_lle_eval", [], ["--cases", "many"]),
    ("lle/alacs_lle_eval", [], ["--set", "nosuch=3"]),
    ("calibrate/alacs_calibrate", [], ["--scans", "d", "--board", "10x7"]),
    ("calibrate/alacs_calibrate", [], ["--scans", "d", "--sigma-draws", "-1"]),
    ("cycle/alacs_cycle", [], ["--cases", "ten"]),
    ("cycle/alacs_cycle", [], ["--mode", "sideways"]),
    ("geometry_eval/alacs_geometry_eval", ["localize"], ["--calibration", "c.json", "--cases", "x"]),
    ("geometry_eval/alacs_geometry_eval", ["calib-scans"], ["--out", "d", "--views", "1.5"]),
    ("geometry_eval/alacs_geometry_eval", ["check-calibration"], ["--calibration", "a", "--truth", "b", "--max-mean-mm", "far"]),
    ("jitter/alacs_step_jitter", [], ["--moves", "x"]),
    ("twin/alacs-twin", ["generate"], ["--set", "lle", "--out", "d", "--count", "many"]),
    ("twin/alacs-twin", ["calib"], ["--out", "d", "--views", "2.5"]),
    ("twin/alacs-twin", ["process"], ["--jobs", "two", "d"]),
    ("twin/alacs-twin", ["examples"], ["--out"]),
    ("twin/alacs-twin", ["render"], ["--out", "x.png", "--slide", "left"]),
    ("bench/alacs_lle_bench", [], ["--frames", "x"]),
]


def build_dir() -> Path | None:
    if os.environ.get("ALACS_TOOLS_BUILD"):
        return Path(os.environ["ALACS_TOOLS_BUILD"])
    builds = sorted((p.parent.parent for p in ROOT.glob("build/*/tools/lle/alacs_lle")),
                    key=lambda p: (p / "tools/lle/alacs_lle").stat().st_mtime, reverse=True)
    return builds[0] if builds else None


def tool(rel: str) -> Path:
    b = build_dir()
    path = b / "tools" / rel if b else None
    if path is None or not path.exists():
        pytest.skip(f"{rel} is not built (set ALACS_TOOLS_BUILD)")
    return path


def run(binary: Path, args: list[str]) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, ASAN_OPTIONS="detect_leaks=0")
    return subprocess.run([str(binary), *args], capture_output=True, text=True, timeout=60, env=env)


def one_line(text: str) -> bool:
    return text.endswith("\n") and text.count("\n") == 1


@pytest.mark.parametrize("rel,sub", sorted({(t[0], tuple(t[1])) for t in TOOLS}))
def test_help_exits_0_on_stdout(rel: str, sub: tuple[str, ...]) -> None:
    r = run(tool(rel), [*sub, "--help"])
    assert r.returncode == 0, r.stderr
    assert "--" in r.stdout and r.stderr == ""


@pytest.mark.parametrize("rel,sub", sorted({(t[0], tuple(t[1])) for t in TOOLS}))
def test_unknown_option_exits_2_with_one_line(rel: str, sub: tuple[str, ...]) -> None:
    r = run(tool(rel), [*sub, "--no-such-option"])
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert one_line(r.stderr), r.stderr
    assert "--no-such-option" in r.stderr


@pytest.mark.parametrize("rel,sub,bad", TOOLS)
def test_bad_value_exits_2_with_one_line(rel: str, sub: list[str], bad: list[str]) -> None:
    r = run(tool(rel), [*sub, *bad])
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert one_line(r.stderr), r.stderr


@pytest.mark.parametrize("rel", ["twin/alacs-twin", "geometry_eval/alacs_geometry_eval"])
def test_unknown_subcommand_exits_2(rel: str) -> None:
    r = run(tool(rel), ["no-such-command"])
    assert r.returncode == 2 and one_line(r.stderr), r.stderr


def test_lle_refuses_a_huge_png_header(tmp_path: Path) -> None:
    """issue 15: a PNG whose header declares 60000 x 60000 is an error (exit 1), not an abort."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 60000, 60000, 8, 2, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b""))
    path = tmp_path / "huge.png"
    path.write_bytes(png)
    r = run(tool("lle/alacs_lle"), [str(path), "--overlay", "none"])
    assert r.returncode == 1, r.stderr
    assert "huge.png" in r.stderr and "60000 x 60000" in r.stderr
