"""The committed golden vectors: up to date, complete, and right bit by bit."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import can
import pytest
from cantools.database import Database

import alacs_can
from alacs_can import golden
from alacs_can.spec import MESSAGES_BY_NAME

GOLDEN_JSON = Path(__file__).resolve().parents[2] / "vectors" / "golden.json"


@pytest.fixture(scope="module")
def doc() -> dict[str, Any]:
    return json.loads(GOLDEN_JSON.read_text(encoding="ascii"))


def _bits(data: bytes, start: int, length: int, signed: bool) -> int:
    """Little-endian bit field, written independently of cantools."""
    value = (int.from_bytes(data, "little") >> start) & ((1 << length) - 1)
    if signed and value & (1 << (length - 1)):
        value -= 1 << length
    return value


def test_committed_file_is_regenerated_output() -> None:
    assert GOLDEN_JSON.read_text(encoding="ascii") == golden.golden_json(), (
        "can_protocol/vectors/golden.json is stale: run can_protocol/generate.sh"
    )


def test_header(doc: dict[str, Any]) -> None:
    assert doc["node_id"] == 0x10
    assert doc["protocol_version"] == alacs_can.PROTOCOL_VERSION
    assert doc["crc8_j1850"]["check_value"] == 0x4B
    names = [v["name"] for v in doc["vectors"]]
    assert len(names) == len(set(names))


def test_every_message_and_page_is_covered(doc: dict[str, Any]) -> None:
    seen: set[tuple[str, str]] = set()
    for v in doc["vectors"]:
        sigs = v["signals"]
        page = next(
            (sigs[k].get("choice", "") for k in ("CmdOpcode", "AckOpcode", "ObjPage") if k in sigs),
            "",
        )
        seen.add((v["message"], page))
        if "CfgPage" in sigs:
            seen.add((v["message"], "SET_CONFIG/" + sigs["CfgPage"]["choice"]))
    expected = {(name, "") for name in alacs_can.BASE_IDS if name not in (
        "ALACS_Command", "ALACS_Ack", "ALACS_ResultObject")}
    expected |= {("ALACS_Command", o.name) for o in alacs_can.Opcode}
    expected |= {("ALACS_Command", "SET_CONFIG/" + p.name) for p in alacs_can.CfgPage}
    expected |= {("ALACS_Ack", o.name) for o in alacs_can.AckOpcode
                 if o.name in ("INVALID", "LOCALIZE", "HOME", "SET_CONFIG", "GET_VERSION", "STOP")}
    expected |= {("ALACS_ResultObject", p.name) for p in alacs_can.ObjPage}
    assert expected <= seen, sorted(expected - seen)


def test_vectors_bit_exact_against_spec(doc: dict[str, Any]) -> None:
    """Raw values sit at the spec's bit positions; physical = raw * scale."""
    for v in doc["vectors"]:
        data = bytes.fromhex(v["data"])
        assert len(data) == v["dlc"] == MESSAGES_BY_NAME[v["message"]].dlc, v["name"]
        assert v["frame_id"] == MESSAGES_BY_NAME[v["message"]].frame_id(0x10)
        covered = 0
        for name, entry in v["signals"].items():
            spec = MESSAGES_BY_NAME[v["message"]].signal(name)
            raw = _bits(data, spec.start, spec.length, spec.signed)
            assert raw == entry["raw"], (v["name"], name)
            assert entry["physical"] == pytest.approx(entry["raw"] * spec.scale, abs=1e-9)
            lo, hi = spec.phys_range()
            assert lo - 1e-9 <= entry["physical"] <= hi + 1e-9, (v["name"], name)
            covered |= ((1 << spec.length) - 1) << spec.start
        # bits no signal of the selected page covers must be zero (reserved)
        assert int.from_bytes(data, "little") & ~covered == 0, v["name"]


def test_commands_carry_correct_crc(doc: dict[str, Any]) -> None:
    commands = [v for v in doc["vectors"] if v["message"] == "ALACS_Command"]
    assert len(commands) >= 10
    for v in commands:
        data = bytes.fromhex(v["data"])
        assert data[7] == alacs_can.crc8_j1850(data[:7]) == v["signals"]["CmdChecksum"]["raw"]


def test_edge_cases_present(doc: dict[str, Any]) -> None:
    raws = {(v["name"], k): e["raw"] for v in doc["vectors"] for k, e in v["signals"].items()}
    assert raws[("command_localize_min", "RoughX")] == -2048
    assert raws[("command_localize_max", "RoughX")] == 2047
    assert raws[("command_localize_minus_one", "RoughY")] == -1
    assert raws[("result_object_center_min", "CenterX")] == -32768
    assert raws[("result_object_center_max", "CenterZ")] == 65535
    assert raws[("result_object_normal_negative", "NormalX")] == -32767
    assert raws[("result_object_quality_max", "PointsUsed")] == 4095


def test_vectors_decode_with_cantools(doc: dict[str, Any], db: Database) -> None:
    """cantools, reading the committed DBC, decodes every vector as the bit reader above does
    and names each value as the spec's enum does. (The stored values are the generator's own
    cantools output, so they are not what it is checked against.)"""
    for v in doc["vectors"]:
        data = bytes.fromhex(v["data"])
        msg = can.Message(arbitration_id=v["frame_id"], data=data, is_extended_id=False)
        spec = MESSAGES_BY_NAME[v["message"]]
        raw = alacs_can.decode_raw(db, msg)
        assert set(raw) == set(v["signals"]), v["name"]
        named = alacs_can.decode(db, msg)
        for k, value in raw.items():
            s = spec.signal(k)
            assert value == _bits(data, s.start, s.length, s.signed), (v["name"], k)
            if s.choices is not None:
                assert named[k] == s.choices(value).name, (v["name"], k)


def test_command_checks(doc: dict[str, Any]) -> None:
    checks = {c["name"]: c for c in doc["command_checks"]}
    assert checks["valid_localize"]["checksum_ok"]
    for chk in checks.values():
        data = bytes.fromhex(chk["data"])
        assert len(data) == chk["dlc"]
        # The CRC-8/SAE-J1850 (its check value is tested above) over bytes 0..6, by hand.
        independent = len(data) == 8 and data[7] == alacs_can.crc8_j1850(data[:7])
        assert alacs_can.check_command(data) == independent == chk["checksum_ok"], chk["name"]
        # A bad length or checksum is what the node NACKs first; any other case passes it.
        assert (chk["expected_nack"] in ("BAD_DLC", "BAD_CHECKSUM")) == (not independent), chk["name"]
        assert chk["expected_nack"] in alacs_can.NackReason.__members__
        if chk["expected_nack"] == "UNKNOWN_OPCODE":
            assert chk["checksum_ok"] and data[0] not in set(alacs_can.Opcode)
