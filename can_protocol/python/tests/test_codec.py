"""encode_command / check_command / decode and friends."""

from __future__ import annotations

import can
import pytest
from cantools.database import Database
from cantools.database.errors import DecodeError, EncodeError

import alacs_can
from alacs_can import AckOpcode, Fault, Opcode, crc8_j1850


def _localize(db: Database, counter: int = 1, **over: object) -> can.Message:
    payload: dict[str, object] = dict(LocalizeMode="STOP_AND_GO", TargetId=3, RoughX=-120,
                                      RoughY=45, RoughZ=650)
    payload.update(over)
    return alacs_can.encode_command(db, "LOCALIZE", counter, **payload)


def test_encode_command_frame(db: Database) -> None:
    msg = _localize(db)
    assert msg.arbitration_id == 0x210
    assert not msg.is_extended_id
    assert msg.dlc == 8
    assert msg.data[0] == Opcode.LOCALIZE
    assert msg.data[1] & 0x0F == 1
    assert msg.data[7] == crc8_j1850(bytes(msg.data[:7]))
    assert alacs_can.check_command(msg.data)


def test_encode_command_hand_computed_bytes(db: Database) -> None:
    # byte0 opcode 1; byte1 counter 5 | mode CONTINUOUS<<4; byte2 target 9;
    # RoughX -1 -> 0xFFF at bits 24..35, RoughY 2 -> 0x002 at 36..47, RoughZ 100 mm -> 10.
    msg = _localize(db, 5, LocalizeMode="CONTINUOUS", TargetId=9, RoughX=-1, RoughY=2, RoughZ=100)
    body = bytes([0x01, 0x15, 0x09, 0xFF, 0x2F, 0x00, 0x0A])
    assert bytes(msg.data) == body + bytes([crc8_j1850(body)])


@pytest.mark.parametrize("opcode", list(Opcode))
def test_every_opcode_round_trips(db: Database, opcode: Opcode) -> None:
    payload: dict[str, object] = {
        Opcode.LOCALIZE: dict(LocalizeMode=1, TargetId=200, RoughX=-300, RoughY=400, RoughZ=1230),
        Opcode.SCAN_ALL: dict(ScanAllMode="CONTINUOUS"),
        Opcode.SET_CONFIG: dict(CfgPage="SCAN", CfgScanStopsValid=1, CfgScanStops=7),
    }.get(opcode, {})
    for counter in (0, 7, 15, 16, 33):
        msg = alacs_can.encode_command(db, opcode.name.lower(), counter, **payload)
        assert alacs_can.check_command(msg.data)
        decoded = alacs_can.decode(db, msg)
        assert decoded["CmdOpcode"] == opcode.name
        assert decoded["CmdCounter"] == counter % 16
        for key, value in payload.items():
            expected = value
            sig = db.get_message_by_name("ALACS_Command").get_signal_by_name(key)
            if sig.choices and isinstance(value, int):
                expected = str(sig.choices[value])
            assert decoded[key] == expected, key


def test_encode_command_accepts_enum_and_int(db: Database) -> None:
    a = alacs_can.encode_command(db, Opcode.HOME, 3)
    b = alacs_can.encode_command(db, 3, 3)
    c = alacs_can.encode_command(db, "home", 3)
    assert bytes(a.data) == bytes(b.data) == bytes(c.data)
    assert bytes(a.data[:7]) == bytes([3, 3, 0, 0, 0, 0, 0])


def test_encode_command_rejects_bad_input(db: Database) -> None:
    with pytest.raises(ValueError):
        alacs_can.encode_command(db, "DANCE", 0)
    with pytest.raises(EncodeError):
        _localize(db, RoughZ=2560)  # above 2550 mm
    with pytest.raises(EncodeError):
        _localize(db, RoughX=-2049)
    with pytest.raises(EncodeError):
        alacs_can.encode_command(db, "LOCALIZE", 0, TargetId=1)  # missing payload


def test_check_command_rejects(db: Database) -> None:
    data = bytearray(_localize(db).data)
    assert alacs_can.check_command(data)
    for i in range(8):
        bad = bytearray(data)
        bad[i] ^= 0x10
        assert not alacs_can.check_command(bad), i
    assert not alacs_can.check_command(data[:7])
    assert not alacs_can.check_command(bytes(data) + b"\x00")
    assert not alacs_can.check_command(b"")


def test_set_config_defaults_and_valid_bits(db: Database) -> None:
    msg = alacs_can.encode_command(db, "SET_CONFIG", 2, CfgPage="ACQUISITION",
                                   CfgExposureValid=1, CfgExposureUs=750)
    d = alacs_can.decode(db, msg)
    assert d["CfgPage"] == "ACQUISITION"
    assert (d["CfgExposureValid"], d["CfgExposureUs"]) == (1, 750)
    assert (d["CfgBrceStepValid"], d["CfgBrceThresholdValid"]) == (0, 0)
    # Unused fields carry their minimum so the frame still satisfies the DBC ranges.
    assert d["CfgBrceStep"] == 1


def test_encode_set_config_pages(db: Database) -> None:
    msgs = alacs_can.encode_set_config(db, 15, exposure_us=900, brce_threshold=30,
                                       stop_spacing_mm=1.5, heartbeat_ms=None)
    assert len(msgs) == 2
    a, b = (alacs_can.decode(db, m) for m in msgs)
    assert (a["CfgPage"], a["CmdCounter"], b["CfgPage"], b["CmdCounter"]) == (
        "ACQUISITION", 15, "SCAN", 0)
    assert (a["CfgExposureValid"], a["CfgExposureUs"]) == (1, 900)
    assert (a["CfgBrceThresholdValid"], a["CfgBrceThreshold"], a["CfgBrceStepValid"]) == (1, 30, 0)
    assert (b["CfgStopSpacingValid"], b["CfgStopSpacingMm"]) == (1, 1.5)
    assert (b["CfgHeartbeatValid"], b["CfgScanStopsValid"]) == (0, 0)
    assert all(alacs_can.check_command(m.data) for m in msgs)
    only_scan = alacs_can.encode_set_config(db, 4, scan_stops=5)
    assert len(only_scan) == 1 and alacs_can.decode(db, only_scan[0])["CfgPage"] == "SCAN"
    with pytest.raises(ValueError):
        alacs_can.encode_set_config(db, 0)
    with pytest.raises(ValueError):
        alacs_can.encode_set_config(db, 0, gain=3)


def test_ack_round_trip_and_invalid_page(db: Database) -> None:
    msg = alacs_can.encode_message(db, "ALACS_Ack", dict(
        AckOpcode="INVALID", AckCounter=3, AckResult="NACK", NackReason="UNKNOWN_OPCODE",
        RejectedOpcode=0x42))
    assert bytes(msg.data) == bytes([0x00, 0x13, 0x04, 0x42, 0, 0, 0, 0])
    d = alacs_can.decode(db, msg)
    assert d["AckOpcode"] == "INVALID" and d["RejectedOpcode"] == 0x42
    assert d["NackReason"] == "UNKNOWN_OPCODE"
    version = alacs_can.encode_message(db, "ALACS_Ack", dict(
        AckOpcode=AckOpcode.GET_VERSION, AckCounter=6, AckResult=0, NackReason=0, SwMajor=1,
        SwMinor=2, SwPatch=3, ProtocolVersion=alacs_can.PROTOCOL_VERSION))
    assert bytes(version.data) == bytes([6, 6, 0, 1, 2, 3, alacs_can.PROTOCOL_VERSION, 0])


def test_decode_numeric_choices(db: Database) -> None:
    d = alacs_can.decode(db, _localize(db), choices=False)
    assert d["CmdOpcode"] == 1 and d["LocalizeMode"] == 0


def test_decode_raw(db: Database) -> None:
    msg = alacs_can.encode_message(db, "ALACS_ResultObject", dict(
        ObjPage="CENTER", ObjIndex=1, ObjMeasCounter=9, CenterX=-0.1, CenterY=12.3, CenterZ=600))
    raw = alacs_can.decode_raw(db, msg)
    assert (raw["CenterX"], raw["CenterY"], raw["CenterZ"]) == (-1, 123, 6000)
    phys = alacs_can.decode(db, msg)
    assert phys["CenterX"] == pytest.approx(-0.1)
    assert phys["CenterZ"] == pytest.approx(600)


def test_decode_errors(db: Database) -> None:
    with pytest.raises(KeyError):
        alacs_can.decode(db, can.Message(arbitration_id=0x123, data=bytes(8), is_extended_id=False))
    with pytest.raises(KeyError):
        alacs_can.decode(db, can.Message(arbitration_id=0x210, data=bytes(8), is_extended_id=True))
    with pytest.raises(DecodeError):  # unknown multiplexer value
        alacs_can.decode(db, can.Message(arbitration_id=0x390, data=b"\x0f" + bytes(7),
                                         is_extended_id=False))
    with pytest.raises(DecodeError):  # short frame
        alacs_can.decode(db, can.Message(arbitration_id=0x490, data=bytes(4),
                                         is_extended_id=False))


def test_message_name(db: Database) -> None:
    assert alacs_can.message_name(db, _localize(db)) == "ALACS_Command"
    other = can.Message(arbitration_id=0x7FF, is_extended_id=False)
    assert alacs_can.message_name(db, other) is None


def test_status_fault_bits(db: Database) -> None:
    sigs: dict[str, object] = dict(State="FAULT", Homed=1, LaserOn=0, Calibrated=1, HomeSwitch=0,
                                   LastLatencyMs=1, MaxLatencyMs=2, DroppedFrames=3,
                                   RxErrorCount=4)
    active = Fault.CAMERA_TIMEOUT | Fault.STOP_REQUESTED
    sigs.update({name: int(bool(flag & active)) for flag, name in alacs_can.FAULT_SIGNALS.items()})
    msg = alacs_can.encode_message(db, "ALACS_Status", sigs)
    # Fault bit n sits at frame bit 8 + n.
    assert int.from_bytes(bytes(msg.data[1:3]), "little") == int(active)
    assert alacs_can.fault_bits(alacs_can.decode(db, msg)) == active


def test_heartbeat_and_nmt(db: Database) -> None:
    hb = alacs_can.encode_message(db, "Heartbeat", {"NmtState": "OPERATIONAL"})
    assert (hb.arbitration_id, hb.dlc, bytes(hb.data)) == (0x710, 1, b"\x05")
    nmt = alacs_can.encode_message(db, "NMT", {"NmtCommand": "START", "NmtNodeId": 0x10})
    assert (nmt.arbitration_id, bytes(nmt.data)) == (0x000, b"\x01\x10")


@pytest.mark.parametrize("node_id", [1, 0x22, 127])
def test_codec_uses_node_ids(node_id: int) -> None:
    db = alacs_can.load_database(node_id)
    msg = alacs_can.encode_command(db, "STOP", 1)
    assert msg.arbitration_id == 0x200 + node_id
    assert alacs_can.decode(db, msg)["CmdOpcode"] == "STOP"


def test_emcy_reason_and_codes() -> None:
    for flag in Fault:
        assert alacs_can.emcy_reason(flag).name == flag.name
        assert flag in alacs_can.FAULT_EMCY_CODE
    assert int(alacs_can.emcy_reason(Fault.HOMING_TIMEOUT)) == 1


def test_public_api() -> None:
    for name in ("load_database", "dbc_text", "crc8_j1850", "encode_command", "check_command",
                 "decode", "ResultCollector", "MSG_COMMAND", "BASE_ID_STATUS", "Opcode",
                 "NackReason", "DEFAULT_NODE_ID"):
        assert name in alacs_can.__all__ and hasattr(alacs_can, name), name
    assert all(hasattr(alacs_can, name) for name in alacs_can.__all__)


def test_decoded_values_are_rounded_to_their_resolution(db: Database) -> None:
    msg = alacs_can.encode_message(db, "ALACS_ResultObject", dict(
        ObjPage="CENTER", ObjIndex=0, ObjMeasCounter=1, CenterX=-19.9, CenterY=56.3,
        CenterZ=612.3))
    d = alacs_can.decode(db, msg)
    assert (repr(d["CenterX"]), repr(d["CenterY"]), repr(d["CenterZ"])) == (
        "-19.9", "56.3", "612.3")
    assert alacs_can.decode(db, msg, rounded=False)["CenterX"] != -19.9  # the binary value
    normal = alacs_can.encode_message(db, "ALACS_ResultObject", dict(
        ObjPage="APPROACH_NORMAL", ObjIndex=0, ObjMeasCounter=1, NormalX=0, NormalY=0.6,
        NormalZ=-0.8))
    assert alacs_can.decode(db, normal)["NormalY"] == 0.59999  # 5 decimals: 1/32767 steps
    assert [alacs_can.scale_decimals(s) for s in (20, 1, 0.5, 0.1, 1 / 32767)] == [0, 0, 1, 1, 5]
