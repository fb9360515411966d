"""The DBC: committed file up to date, loads strictly, matches the written contract."""

from __future__ import annotations

from pathlib import Path

import cantools
import pytest
from cantools.database import Database

import alacs_can
from alacs_can import constants as c

COMMITTED_DBC = Path(__file__).resolve().parents[2] / "alacs.dbc"

# The contract as written in the protocol brief, which other components code against:
# message -> (frame id for node 0x10, DLC, {signal: (start, length, signed, scale)}).
CONTRACT: dict[str, tuple[int, int, dict[str, tuple[int, int, bool, float]]]] = {
    "ALACS_Command": (0x210, 8, {
        "CmdOpcode": (0, 8, False, 1), "CmdCounter": (8, 4, False, 1),
        "CmdChecksum": (56, 8, False, 1),
        "LocalizeMode": (12, 4, False, 1), "TargetId": (16, 8, False, 1),
        "RoughX": (24, 12, True, 1), "RoughY": (36, 12, True, 1), "RoughZ": (48, 8, False, 10),
        "ScanAllMode": (12, 4, False, 1),
    }),
    "ALACS_Ack": (0x190, 8, {
        "AckOpcode": (0, 8, False, 1), "AckCounter": (8, 4, False, 1),
        "AckResult": (12, 4, False, 1), "NackReason": (16, 8, False, 1),
        "SwMajor": (24, 8, False, 1), "SwMinor": (32, 8, False, 1), "SwPatch": (40, 8, False, 1),
        "ProtocolVersion": (48, 8, False, 1),
        "NackDetail": (24, 8, False, 1), "NackValue": (32, 16, True, 0.1),
        "NackLimit": (48, 16, True, 0.1),
    }),
    "ALACS_Progress": (0x690, 8, {
        "ProgressMeasCounter": (0, 16, False, 1), "ProgressCounter": (16, 4, False, 1),
        "ProgressMode": (20, 4, False, 1), "ProgressPhase": (24, 4, False, 1),
        "StopsDone": (32, 8, False, 1), "StopsTotal": (40, 8, False, 1),
        "ObjectsFound": (48, 8, False, 1), "ElapsedS": (56, 8, False, 0.5),
    }),
    "ALACS_ResultHeader": (0x290, 8, {
        "MeasCounter": (0, 16, False, 1), "ObjectCount": (16, 5, False, 1),
        "ResultMode": (21, 3, False, 1),
        "ResultTargetId": (24, 8, False, 1), "ScanAgeMs": (32, 16, False, 1),
        "ResultStatus": (48, 4, False, 1), "ResultReason": (52, 4, False, 1),
        "CycleTime": (56, 8, False, 20),
    }),
    "ALACS_ResultObject": (0x390, 8, {
        "ObjPage": (0, 4, False, 1), "ObjIndex": (4, 4, False, 1),
        "ObjMeasCounter": (8, 8, False, 1),
        "CenterX": (16, 16, True, 0.1), "CenterY": (32, 16, True, 0.1),
        "CenterZ": (48, 16, False, 0.1),
        "ApproachX": (16, 16, True, 0.1), "ApproachY": (32, 16, True, 0.1),
        "ApproachZ": (48, 16, False, 0.1),
        "SigmaMm": (16, 8, False, 0.1), "Confidence": (24, 8, False, 1),
        "DiameterMm": (32, 8, False, 0.5), "OcclusionPct": (40, 8, False, 1),
        "LinesUsed": (48, 4, False, 1), "PointsUsed": (52, 12, False, 1),
        "NormalX": (16, 16, True, 1 / 32767), "NormalY": (32, 16, True, 1 / 32767),
        "NormalZ": (48, 16, True, 1 / 32767),
    }),
    "ALACS_Status": (0x490, 8, {
        "State": (0, 4, False, 1), "Homed": (4, 1, False, 1), "LaserOn": (5, 1, False, 1),
        "Calibrated": (6, 1, False, 1), "HomeSwitch": (7, 1, False, 1),
        "FaultHomingTimeout": (8, 1, False, 1), "FaultLimitHit": (9, 1, False, 1),
        "FaultCameraTimeout": (10, 1, False, 1), "FaultCameraCorrupt": (11, 1, False, 1),
        "FaultCanBusOff": (12, 1, False, 1), "FaultCanTxOverflow": (13, 1, False, 1),
        "FaultConfigInvalid": (14, 1, False, 1), "FaultNotCalibrated": (15, 1, False, 1),
        "FaultLaserOvertime": (16, 1, False, 1), "FaultInternal": (17, 1, False, 1),
        "FaultStopRequested": (18, 1, False, 1),
        "LastLatencyMs": (24, 12, False, 1), "MaxLatencyMs": (36, 12, False, 1),
        "DroppedFrames": (48, 8, False, 1), "RxErrorCount": (56, 8, False, 1),
    }),
    "NMT": (0x000, 2, {"NmtCommand": (0, 8, False, 1), "NmtNodeId": (8, 8, False, 1)}),
    "Heartbeat": (0x710, 1, {"NmtState": (0, 8, False, 1)}),
    "EMCY": (0x090, 8, {
        "EmcyErrorCode": (0, 16, False, 1), "EmcyErrorRegister": (16, 8, False, 1),
        "EmcyFaultBits": (24, 16, False, 1), "EmcyReason": (40, 8, False, 1),
    }),
    "SDO_Tx": (0x590, 8, {
        "SdoTxCommand": (0, 8, False, 1), "SdoTxIndex": (8, 16, False, 1),
        "SdoTxSubIndex": (24, 8, False, 1), "SdoTxData": (32, 32, False, 1),
    }),
    "SDO_Rx": (0x610, 8, {
        "SdoRxCommand": (0, 8, False, 1), "SdoRxIndex": (8, 16, False, 1),
        "SdoRxSubIndex": (24, 8, False, 1), "SdoRxData": (32, 32, False, 1),
    }),
}

CONTRACT_CHOICES: dict[tuple[str, str], dict[int, str]] = {
    ("ALACS_Command", "CmdOpcode"): {1: "LOCALIZE", 2: "SCAN_ALL", 3: "HOME", 4: "STOP",
                                     5: "SET_CONFIG", 6: "GET_VERSION", 7: "CLEAR_FAULT"},
    ("ALACS_Command", "LocalizeMode"): {0: "STOP_AND_GO", 1: "CONTINUOUS"},
    ("ALACS_Command", "ScanAllMode"): {0: "STOP_AND_GO", 1: "CONTINUOUS"},
    ("ALACS_Ack", "AckResult"): {0: "ACK", 1: "NACK", 2: "DONE"},
    ("ALACS_Ack", "NackReason"): {
        0: "NONE", 1: "BAD_DLC", 2: "BAD_CHECKSUM", 3: "BAD_COUNTER", 4: "UNKNOWN_OPCODE",
        5: "BUSY", 6: "NOT_HOMED", 7: "NOT_CALIBRATED", 8: "OUT_OF_RANGE", 9: "FAULT_ACTIVE",
        10: "NMT_NOT_OPERATIONAL", 11: "BAD_VALUE", 12: "INTERNAL"},
    ("ALACS_ResultHeader", "ResultStatus"): {0: "MEASURED", 1: "NOT_FOUND", 2: "ROUGH_ONLY",
                                             3: "FAILED", 4: "ABORTED", 5: "AMBIGUOUS"},
    ("ALACS_ResultHeader", "ResultReason"): {
        0: "NONE", 1: "NO_LINES_IN_GATE", 2: "TOO_FEW_LINES", 3: "FIT_FAILED",
        4: "TWO_SURFACES", 5: "FAR_FROM_ROUGH", 6: "CAMERA_FAULT", 7: "MOTION_FAULT",
        8: "LASER_FAULT", 9: "STOPPED", 10: "SHUTDOWN", 11: "INTERNAL", 12: "OUTSIDE_GATE",
        13: "BRIGHT_AMBIENT"},
    ("ALACS_Ack", "NackDetail"): {
        0: "NONE", 1: "STROKE", 2: "DEPTH", 3: "LATERAL", 4: "FRAME", 5: "CROSS_FIELD",
        6: "SPACING_X_STOPS", 7: "MODE", 8: "EXPOSURE", 9: "BRCE_STEP", 10: "SCAN_STOPS",
        11: "STOP_SPACING", 12: "HEARTBEAT"},
    ("ALACS_Progress", "ProgressPhase"): {0: "MOVING", 1: "EXPOSING", 2: "FITTING",
                                         3: "SECOND_PASS"},
    ("ALACS_ResultHeader", "ResultMode"): {0: "LOCALIZE", 1: "SCAN_ALL"},
    ("ALACS_ResultObject", "ObjPage"): {0: "CENTER", 1: "APPROACH_POINT", 2: "QUALITY",
                                        3: "APPROACH_NORMAL"},
    ("ALACS_Status", "State"): {0: "BOOT", 1: "HOMING", 2: "IDLE", 3: "SCANNING", 4: "FAULT",
                                5: "STOPPED"},
    ("NMT", "NmtCommand"): {1: "START", 2: "STOP", 128: "PRE_OPERATIONAL", 129: "RESET_NODE",
                            130: "RESET_COMM"},
    ("Heartbeat", "NmtState"): {0: "BOOTUP", 4: "STOPPED", 5: "OPERATIONAL",
                                127: "PRE_OPERATIONAL"},
}


def test_committed_dbc_is_generated_text() -> None:
    assert COMMITTED_DBC.read_text(encoding="ascii") == alacs_can.dbc_text(0x10), (
        "can_protocol/alacs.dbc is stale: run can_protocol/generate.sh"
    )


def test_committed_dbc_loads_strict() -> None:
    db = cantools.database.load_file(str(COMMITTED_DBC), strict=True)
    assert {m.name for m in db.messages} == set(c.BASE_IDS)


@pytest.mark.parametrize("name", sorted(CONTRACT))
def test_layout_matches_contract(db: Database, name: str) -> None:
    frame_id, dlc, signals = CONTRACT[name]
    msg = db.get_message_by_name(name)
    assert msg.frame_id == frame_id
    assert msg.length == dlc
    assert not msg.is_extended_frame
    for sig_name, (start, length, signed, scale) in signals.items():
        sig = msg.get_signal_by_name(sig_name)
        assert (sig.start, sig.length, sig.is_signed) == (start, length, signed), sig_name
        assert sig.byte_order == "little_endian", sig_name
        assert sig.scale == pytest.approx(scale, rel=1e-12), sig_name
        assert sig.offset == 0


@pytest.mark.parametrize(("key", "table"), sorted(CONTRACT_CHOICES.items()))
def test_value_tables_match_contract(db: Database, key: tuple[str, str],
                                     table: dict[int, str]) -> None:
    sig = db.get_message_by_name(key[0]).get_signal_by_name(key[1])
    assert sig.choices is not None
    assert {int(k): str(v) for k, v in sig.choices.items()} == table


def test_ack_opcode_table_is_opcodes_plus_invalid(db: Database) -> None:
    sig = db.get_message_by_name("ALACS_Ack").get_signal_by_name("AckOpcode")
    assert sig.choices is not None
    expected = {0: "INVALID", **{int(o): o.name for o in c.Opcode}}
    assert {int(k): str(v) for k, v in sig.choices.items()} == expected


def test_multiplexers(db: Database) -> None:
    assert db.get_message_by_name("ALACS_Command").get_signal_by_name("CmdOpcode").is_multiplexer
    assert db.get_message_by_name("ALACS_Ack").get_signal_by_name("AckOpcode").is_multiplexer
    assert db.get_message_by_name("ALACS_ResultObject").get_signal_by_name("ObjPage").is_multiplexer
    cfg = db.get_message_by_name("ALACS_Command").get_signal_by_name("CfgPage")
    assert cfg.is_multiplexer and cfg.multiplexer_signal == "CmdOpcode"
    assert cfg.multiplexer_ids == [int(c.Opcode.SET_CONFIG)]


def test_nack_detail_in_every_ack_page_with_free_bytes(db: Database) -> None:
    msg = db.get_message_by_name("ALACS_Ack")
    expected = sorted(int(o) for o in c.Opcode if o is not c.Opcode.GET_VERSION)
    for name in ("NackDetail", "NackValue", "NackLimit"):
        assert msg.get_signal_by_name(name).multiplexer_ids == expected, name
    frame = alacs_can.encode_message(db, "ALACS_Ack", dict(
        AckOpcode="LOCALIZE", AckCounter=5, AckResult="NACK", NackReason="OUT_OF_RANGE",
        NackDetail="STROKE", NackValue=-239.6, NackLimit=0))
    assert bytes(frame.data) == bytes([1, 0x15, 8, 1, 0xA4, 0xF6, 0, 0])
    d = alacs_can.decode(db, frame)
    assert d["NackDetail"] == "STROKE" and d["NackValue"] == pytest.approx(-239.6)


def test_result_header_outcome_byte(db: Database) -> None:
    frame = alacs_can.encode_message(db, "ALACS_ResultHeader", dict(
        MeasCounter=1, ObjectCount=16, ResultMode="SCAN_ALL", ResultTargetId=0, ScanAgeMs=0,
        ResultStatus="AMBIGUOUS", ResultReason="TWO_SURFACES", CycleTime=0))
    # byte 2: ObjectCount in bits 0..4, ResultMode in bits 5..7; byte 6: status | reason << 4
    assert frame.data[2] == 16 | 1 << 5 and frame.data[6] == 5 | 4 << 4


def test_set_config_fits_bits_12_to_55(db: Database) -> None:
    msg = db.get_message_by_name("ALACS_Command")
    cfg = [s for s in msg.signals if s.name.startswith("Cfg")]
    assert len(cfg) == 13
    for sig in cfg:
        assert 12 <= sig.start and sig.start + sig.length <= 56, sig.name


@pytest.mark.parametrize("node_id", [1, 0x10, 0x2A, 127])
def test_node_id_offset(node_id: int) -> None:
    db = alacs_can.load_database(node_id)
    for name, base in c.BASE_IDS.items():
        expected = base if name == "NMT" else base + node_id
        assert db.get_message_by_name(name).frame_id == expected
        assert alacs_can.frame_id(name, node_id) == expected
    assert f"sensor node id {node_id} " in alacs_can.dbc_text(node_id)


@pytest.mark.parametrize("node_id", [0, 128, -1, 0x200])
def test_invalid_node_id_rejected(node_id: int) -> None:
    with pytest.raises(ValueError):
        alacs_can.dbc_text(node_id)
    with pytest.raises(ValueError):
        alacs_can.frame_id("ALACS_Status", node_id)


def test_two_sensors_do_not_collide() -> None:
    ids_a = {m.frame_id for m in alacs_can.load_database(0x10).messages if m.name != "NMT"}
    ids_b = {m.frame_id for m in alacs_can.load_database(0x11).messages if m.name != "NMT"}
    assert not ids_a & ids_b


def test_every_signal_documented(db: Database) -> None:
    for msg in db.messages:
        assert msg.comment, msg.name
        assert msg.senders and msg.senders[0] in ("ALACS", "ARM"), msg.name
        for sig in msg.signals:
            assert sig.comment, f"{msg.name}.{sig.name}"
            assert sig.minimum is not None and sig.maximum is not None, sig.name
            assert sig.minimum <= sig.maximum, sig.name
            assert sig.receivers in (["ALACS"], ["ARM"]), sig.name
            assert sig.receivers != msg.senders, sig.name
            # NackValue/NackLimit: the unit is the one NackDetail names (mm, ms, count).
            if sig.scale != 1 and not sig.name.startswith("Normal") and sig.name not in (
                    "NackValue", "NackLimit"):
                assert sig.unit, f"{msg.name}.{sig.name} is scaled but has no unit"


def test_units(db: Database) -> None:
    units = {(m.name, s.name): s.unit for m in db.messages for s in m.signals}
    for key in [("ALACS_Command", "RoughX"), ("ALACS_Command", "RoughZ"),
                ("ALACS_ResultObject", "CenterX"), ("ALACS_ResultObject", "ApproachZ"),
                ("ALACS_ResultObject", "SigmaMm"), ("ALACS_ResultObject", "DiameterMm"),
                ("ALACS_Command", "CfgStopSpacingMm")]:
        assert units[key] == "mm", key
    for key in [("ALACS_ResultHeader", "ScanAgeMs"), ("ALACS_ResultHeader", "CycleTime"),
                ("ALACS_Status", "LastLatencyMs"), ("ALACS_Status", "MaxLatencyMs"),
                ("ALACS_Command", "CfgHeartbeatMs")]:
        assert units[key] == "ms", key
    assert units[("ALACS_Command", "CfgExposureUs")] == "us"
    assert units[("ALACS_ResultObject", "Confidence")] == "%"


def test_physical_ranges(db: Database) -> None:
    def rng(msg: str, sig: str) -> tuple[float, float]:
        s = db.get_message_by_name(msg).get_signal_by_name(sig)
        return s.minimum, s.maximum  # type: ignore[return-value]

    assert rng("ALACS_Command", "RoughZ") == (0, 2550)
    assert rng("ALACS_Command", "RoughX") == (-2048, 2047)
    assert rng("ALACS_Command", "CfgStopSpacingMm") == (0, 25.5)
    assert rng("ALACS_Command", "CfgBrceStep") == (1, 15)
    assert rng("ALACS_Command", "CfgScanStops") == (1, 15)
    assert rng("ALACS_ResultObject", "CenterX") == (-3276.8, 3276.7)
    assert rng("ALACS_ResultObject", "CenterZ") == (0, 6553.5)
    assert rng("ALACS_ResultObject", "Confidence") == (0, 100)
    assert rng("ALACS_ResultObject", "NormalX") == (-1, 1)
    assert rng("ALACS_ResultHeader", "CycleTime") == (0, 5100)
    assert rng("ALACS_ResultObject", "PointsUsed") == (0, 4095)


def test_cycle_times(db: Database) -> None:
    cycles = {m.name: m.cycle_time for m in db.messages}
    assert cycles["ALACS_Status"] == 100
    assert cycles["Heartbeat"] == c.DEFAULT_HEARTBEAT_MS == 1000
    assert all(not cycles[n] for n in cycles if n not in ("ALACS_Status", "Heartbeat"))


def test_nodes_and_directions(db: Database) -> None:
    assert [n.name for n in db.nodes] == ["ALACS", "ARM"]
    from_arm = {m.name for m in db.messages if m.senders == ["ARM"]}
    assert from_arm == {"ALACS_Command", "NMT", "SDO_Rx"}


def test_dbc_is_ascii_and_has_no_tabs_in_signals() -> None:
    text = alacs_can.dbc_text(0x10)
    text.encode("ascii")
    assert 'BA_ "GenMsgCycleTime" BO_ 1168 100;' in text
