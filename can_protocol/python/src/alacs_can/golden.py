"""Golden vectors: known frames with their physical and raw signal values.

``python -m alacs_can golden -o can_protocol/vectors/golden.json`` writes the
committed file (``can_protocol/generate.sh`` does it); the pytest suite recomputes
it and fails if it differs, and the C/C++ tests read it to check their codecs.
Every frame is encoded by cantools from the DBC; commands carry the right CRC.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from typing import Any

import can
from cantools.database import Database

from . import constants as c
from . import sdo
from .codec import (
    check_command,
    command_checksum,
    decode,
    decode_raw,
    encode_command,
    encode_message,
)
from .crc import CRC8_J1850_INIT, CRC8_J1850_POLY, CRC8_J1850_XOROUT, crc8_j1850
from .dbc import load_database
from .output import write_text
from .spec import OD_ENTRIES

FORMAT_VERSION = 1

# (name, opcode, counter, payload) for ALACS_Command.
COMMAND_CASES: list[tuple[str, str, int, dict[str, Any]]] = [
    ("command_localize_typical", "LOCALIZE", 1,
     dict(LocalizeMode="STOP_AND_GO", TargetId=3, RoughX=-120, RoughY=45, RoughZ=650)),
    ("command_localize_min", "LOCALIZE", 0,
     dict(LocalizeMode="STOP_AND_GO", TargetId=0, RoughX=-2048, RoughY=-2048, RoughZ=0)),
    ("command_localize_max", "LOCALIZE", 15,
     dict(LocalizeMode="CONTINUOUS", TargetId=255, RoughX=2047, RoughY=2047, RoughZ=2550)),
    ("command_localize_minus_one", "LOCALIZE", 7,
     dict(LocalizeMode="CONTINUOUS", TargetId=128, RoughX=-1, RoughY=-1, RoughZ=10)),
    ("command_scan_all_stop_and_go", "SCAN_ALL", 2, dict(ScanAllMode="STOP_AND_GO")),
    ("command_scan_all_continuous", "SCAN_ALL", 3, dict(ScanAllMode="CONTINUOUS")),
    ("command_home", "HOME", 4, {}),
    ("command_stop", "STOP", 5, {}),
    ("command_get_version", "GET_VERSION", 6, {}),
    ("command_clear_fault", "CLEAR_FAULT", 8, {}),
    ("command_set_config_acquisition", "SET_CONFIG", 9,
     dict(CfgPage="ACQUISITION", CfgExposureValid=1, CfgExposureUs=800, CfgBrceStepValid=1,
          CfgBrceStep=4, CfgBrceThresholdValid=1, CfgBrceThreshold=40)),
    ("command_set_config_acquisition_max", "SET_CONFIG", 10,
     dict(CfgPage="ACQUISITION", CfgExposureValid=1, CfgExposureUs=65535, CfgBrceStepValid=1,
          CfgBrceStep=15, CfgBrceThresholdValid=1, CfgBrceThreshold=255)),
    ("command_set_config_exposure_only", "SET_CONFIG", 11,
     dict(CfgPage="ACQUISITION", CfgExposureValid=1, CfgExposureUs=1200)),
    ("command_set_config_scan", "SET_CONFIG", 12,
     dict(CfgPage="SCAN", CfgScanStopsValid=1, CfgScanStops=9, CfgStopSpacingValid=1,
          CfgStopSpacingMm=2.5, CfgHeartbeatValid=1, CfgHeartbeatMs=1000)),
    ("command_set_config_scan_max", "SET_CONFIG", 13,
     dict(CfgPage="SCAN", CfgScanStopsValid=1, CfgScanStops=15, CfgStopSpacingValid=1,
          CfgStopSpacingMm=25.5, CfgHeartbeatValid=1, CfgHeartbeatMs=65535)),
    ("command_set_config_heartbeat_only", "SET_CONFIG", 14,
     dict(CfgPage="SCAN", CfgHeartbeatValid=1, CfgHeartbeatMs=0)),
]

# (name, message, physical signals) for everything else.
MESSAGE_CASES: list[tuple[str, str, dict[str, Any]]] = [
    ("ack_localize", c.MSG_ACK,
     dict(AckOpcode="LOCALIZE", AckCounter=1, AckResult="ACK", NackReason="NONE", NackDetail="NONE", NackValue=0, NackLimit=0)),
    ("ack_localize_nack_busy", c.MSG_ACK,
     dict(AckOpcode="LOCALIZE", AckCounter=15, AckResult="NACK", NackReason="BUSY", NackDetail="NONE", NackValue=0, NackLimit=0)),
    ("ack_home_done", c.MSG_ACK,
     dict(AckOpcode="HOME", AckCounter=4, AckResult="DONE", NackReason="NONE", NackDetail="NONE", NackValue=0, NackLimit=0)),
    ("ack_set_config_nack_bad_value", c.MSG_ACK,
     dict(AckOpcode="SET_CONFIG", AckCounter=9, AckResult="NACK", NackReason="BAD_VALUE",
          NackDetail="SPACING_X_STOPS", NackValue=266, NackLimit=200)),
    ("ack_localize_nack_stroke", c.MSG_ACK,
     dict(AckOpcode="LOCALIZE", AckCounter=5, AckResult="NACK", NackReason="OUT_OF_RANGE",
          NackDetail="STROKE", NackValue=-239.6, NackLimit=0)),
    ("ack_localize_nack_depth", c.MSG_ACK,
     dict(AckOpcode="LOCALIZE", AckCounter=6, AckResult="NACK", NackReason="OUT_OF_RANGE",
          NackDetail="DEPTH", NackValue=2550, NackLimit=2000)),
    ("ack_scan_all_nack_limits", c.MSG_ACK,
     dict(AckOpcode="SCAN_ALL", AckCounter=7, AckResult="NACK", NackReason="BAD_VALUE",
          NackDetail="HEARTBEAT", NackValue=-3276.8, NackLimit=3276.7)),
    ("ack_get_version", c.MSG_ACK,
     dict(AckOpcode="GET_VERSION", AckCounter=6, AckResult="ACK", NackReason="NONE",
          SwMajor=1, SwMinor=2, SwPatch=3, ProtocolVersion=c.PROTOCOL_VERSION)),
    ("ack_get_version_max", c.MSG_ACK,
     dict(AckOpcode="GET_VERSION", AckCounter=15, AckResult="ACK", NackReason="NONE",
          SwMajor=255, SwMinor=255, SwPatch=255, ProtocolVersion=255)),
    ("ack_invalid_unknown_opcode", c.MSG_ACK,
     dict(AckOpcode="INVALID", AckCounter=3, AckResult="NACK", NackReason="UNKNOWN_OPCODE",
          RejectedOpcode=0x42)),
    ("ack_invalid_bad_dlc_empty", c.MSG_ACK,
     dict(AckOpcode="INVALID", AckCounter=0, AckResult="NACK", NackReason="BAD_DLC",
          RejectedOpcode=0)),
    ("ack_stop_nack_internal", c.MSG_ACK,
     dict(AckOpcode="STOP", AckCounter=2, AckResult="NACK", NackReason="INTERNAL", NackDetail="NONE", NackValue=0, NackLimit=0)),
    ("result_header_measured_one", c.MSG_RESULT_HEADER,
     dict(MeasCounter=42, ObjectCount=1, ResultTargetId=3, ScanAgeMs=35,
          ResultStatus="MEASURED", ResultReason="NONE", ResultMode="LOCALIZE", CycleTime=860)),
    ("result_header_not_found", c.MSG_RESULT_HEADER,
     dict(MeasCounter=0, ObjectCount=0, ResultTargetId=0, ScanAgeMs=0,
          ResultStatus="NOT_FOUND", ResultReason="NO_LINES_IN_GATE", ResultMode="LOCALIZE",
          CycleTime=0)),
    ("result_header_rough_only", c.MSG_RESULT_HEADER,
     dict(MeasCounter=43, ObjectCount=1, ResultTargetId=4, ScanAgeMs=20,
          ResultStatus="ROUGH_ONLY", ResultReason="TOO_FEW_LINES", ResultMode="LOCALIZE",
          CycleTime=900)),
    ("result_header_ambiguous", c.MSG_RESULT_HEADER,
     dict(MeasCounter=44, ObjectCount=0, ResultTargetId=5, ScanAgeMs=20,
          ResultStatus="AMBIGUOUS", ResultReason="TWO_SURFACES", ResultMode="LOCALIZE",
          CycleTime=1000)),
    ("result_header_max", c.MSG_RESULT_HEADER,
     dict(MeasCounter=65535, ObjectCount=16, ResultTargetId=255, ScanAgeMs=65535,
          ResultStatus="ABORTED", ResultReason="INTERNAL", ResultMode="SCAN_ALL",
          CycleTime=5100)),
    ("progress_localize_exposing", c.MSG_PROGRESS,
     dict(ProgressMeasCounter=42, ProgressCounter=3, ProgressMode="LOCALIZE",
          ProgressPhase="EXPOSING", StopsDone=2, StopsTotal=7, ObjectsFound=0, ElapsedS=0.5)),
    ("progress_scan_all_max", c.MSG_PROGRESS,
     dict(ProgressMeasCounter=65535, ProgressCounter=15, ProgressMode="SCAN_ALL",
          ProgressPhase="SECOND_PASS", StopsDone=255, StopsTotal=255, ObjectsFound=255,
          ElapsedS=127.5)),
    ("result_object_center_typical", c.MSG_RESULT_OBJECT,
     dict(ObjPage="CENTER", ObjIndex=0, ObjMeasCounter=42, CenterX=-123.4, CenterY=56.7,
          CenterZ=612.3)),
    ("result_object_center_min", c.MSG_RESULT_OBJECT,
     dict(ObjPage="CENTER", ObjIndex=0, ObjMeasCounter=0, CenterX=-3276.8, CenterY=-3276.8,
          CenterZ=0)),
    ("result_object_center_max", c.MSG_RESULT_OBJECT,
     dict(ObjPage="CENTER", ObjIndex=15, ObjMeasCounter=255, CenterX=3276.7, CenterY=3276.7,
          CenterZ=6553.5)),
    ("result_object_approach_typical", c.MSG_RESULT_OBJECT,
     dict(ObjPage="APPROACH_POINT", ObjIndex=0, ObjMeasCounter=42, ApproachX=-110.2,
          ApproachY=50.1, ApproachZ=540.0)),
    ("result_object_approach_minus_tenth", c.MSG_RESULT_OBJECT,
     dict(ObjPage="APPROACH_POINT", ObjIndex=1, ObjMeasCounter=43, ApproachX=-0.1,
          ApproachY=-0.1, ApproachZ=0.1)),
    ("result_object_quality_typical", c.MSG_RESULT_OBJECT,
     dict(ObjPage="QUALITY", ObjIndex=0, ObjMeasCounter=42, SigmaMm=0.8, Confidence=93,
          DiameterMm=78.5, OcclusionPct=20, LinesUsed=9, PointsUsed=1234)),
    ("result_object_quality_max", c.MSG_RESULT_OBJECT,
     dict(ObjPage="QUALITY", ObjIndex=15, ObjMeasCounter=255, SigmaMm=25.5, Confidence=100,
          DiameterMm=127.5, OcclusionPct=100, LinesUsed=15, PointsUsed=4095)),
    ("result_object_normal_forward", c.MSG_RESULT_OBJECT,
     dict(ObjPage="APPROACH_NORMAL", ObjIndex=0, ObjMeasCounter=42, NormalX=0, NormalY=0,
          NormalZ=1)),
    ("result_object_normal_negative", c.MSG_RESULT_OBJECT,
     dict(ObjPage="APPROACH_NORMAL", ObjIndex=2, ObjMeasCounter=7, NormalX=-1, NormalY=0.6,
          NormalZ=-0.8)),
    ("status_idle_homed", c.MSG_STATUS,
     dict(State="IDLE", Homed=1, LaserOn=0, Calibrated=1, HomeSwitch=0,
          **{s: 0 for s in c.FAULT_SIGNALS.values()},
          LastLatencyMs=180, MaxLatencyMs=240, DroppedFrames=0, RxErrorCount=0)),
    ("status_fault_all_max", c.MSG_STATUS,
     dict(State="FAULT", Homed=1, LaserOn=1, Calibrated=1, HomeSwitch=1,
          **{s: 1 for s in c.FAULT_SIGNALS.values()},
          LastLatencyMs=4095, MaxLatencyMs=4095, DroppedFrames=255, RxErrorCount=255)),
    ("status_boot_camera_timeout", c.MSG_STATUS,
     dict(State="BOOT", Homed=0, LaserOn=0, Calibrated=0, HomeSwitch=0,
          **{s: int(f == c.Fault.CAMERA_TIMEOUT) for f, s in c.FAULT_SIGNALS.items()},
          LastLatencyMs=0, MaxLatencyMs=0, DroppedFrames=3, RxErrorCount=1)),
    ("nmt_start_sensor", c.MSG_NMT, dict(NmtCommand="START", NmtNodeId=c.DEFAULT_NODE_ID)),
    ("nmt_reset_all", c.MSG_NMT, dict(NmtCommand="RESET_NODE", NmtNodeId=0)),
    ("heartbeat_bootup", c.MSG_HEARTBEAT, dict(NmtState="BOOTUP")),
    ("heartbeat_operational", c.MSG_HEARTBEAT, dict(NmtState="OPERATIONAL")),
    ("heartbeat_pre_operational", c.MSG_HEARTBEAT, dict(NmtState="PRE_OPERATIONAL")),
    ("emcy_camera_timeout", c.MSG_EMCY,
     dict(EmcyErrorCode="HARDWARE", EmcyErrorRegister=0x01,
          EmcyFaultBits=int(c.Fault.CAMERA_TIMEOUT), EmcyReason="CAMERA_TIMEOUT")),
    ("emcy_cleared", c.MSG_EMCY,
     dict(EmcyErrorCode="NO_ERROR", EmcyErrorRegister=0, EmcyFaultBits=0, EmcyReason="NONE")),
    *((f"emcy_{f.name.lower()}", c.MSG_EMCY,
       dict(EmcyErrorCode=c.FAULT_EMCY_CODE[f].name, EmcyErrorRegister=c.error_register(f),
            EmcyFaultBits=int(f), EmcyReason=c.emcy_reason(f).name))
      for f in c.Fault if f != c.Fault.CAMERA_TIMEOUT),
    ("sdo_rx_upload_request", c.MSG_SDO_RX,
     dict(SdoRxCommand="UPLOAD_REQUEST", SdoRxIndex=0x1018, SdoRxSubIndex=1, SdoRxData=0)),
    ("sdo_tx_upload_4b", c.MSG_SDO_TX,
     dict(SdoTxCommand="UPLOAD_4B", SdoTxIndex=0x1018, SdoTxSubIndex=1, SdoTxData=0xFFFFFFFF)),
]


def _number(value: float | int) -> float | int:
    if isinstance(value, int):
        return value
    # Keep the JSON free of binary noise like 56.300000000000004.
    rounded = round(float(value), 9)
    return int(rounded) if rounded.is_integer() and abs(rounded) < 2**53 else rounded


def _vector(db: Database, name: str, msg: can.Message) -> dict[str, Any]:
    db_msg = db.get_message_by_frame_id(msg.arbitration_id)
    physical = decode(db, msg, choices=False, rounded=False)
    named = decode(db, msg, choices=True)
    raw = decode_raw(db, msg)
    signals: dict[str, Any] = {}
    for sig_name, value in physical.items():
        entry: dict[str, Any] = {"raw": raw[sig_name], "physical": _number(float(value))}
        if isinstance(named[sig_name], str):
            entry["choice"] = named[sig_name]
        unit = db_msg.get_signal_by_name(sig_name).unit
        if unit:
            entry["unit"] = unit
        signals[sig_name] = entry
    return {
        "name": name,
        "message": db_msg.name,
        "frame_id": msg.arbitration_id,
        "dlc": msg.dlc,
        "data": bytes(msg.data).hex().upper(),
        "signals": signals,
    }


def _command_checks(db: Database) -> list[dict[str, Any]]:
    """Frames a command parser must accept or reject, with the expected NACK reason."""
    fid = db.get_message_by_name(c.MSG_COMMAND).frame_id
    good = bytes(encode_command(db, "LOCALIZE", 1, LocalizeMode=0, TargetId=3, RoughX=-120,
                                RoughY=45, RoughZ=650).data)
    bad_crc = bytearray(good)
    bad_crc[7] ^= 0x01
    flipped = bytearray(good)
    flipped[3] ^= 0x80
    unknown = bytearray([0x09, 0x01, 0, 0, 0, 0, 0, 0])
    unknown[7] = command_checksum(unknown)
    zero = bytearray(8)
    zero[7] = command_checksum(zero)
    cases = [
        ("valid_localize", good, "NONE"),
        ("bad_checksum_byte7", bytes(bad_crc), "BAD_CHECKSUM"),
        ("bad_checksum_payload_bit", bytes(flipped), "BAD_CHECKSUM"),
        ("bad_dlc_7", good[:7], "BAD_DLC"),
        ("bad_dlc_0", b"", "BAD_DLC"),
        ("unknown_opcode_9", bytes(unknown), "UNKNOWN_OPCODE"),
        ("unknown_opcode_0", bytes(zero), "UNKNOWN_OPCODE"),
    ]
    return [
        {
            "name": name,
            "frame_id": fid,
            "dlc": len(data),
            "data": data.hex().upper(),
            "checksum_ok": check_command(data),
            "expected_nack": reason,
        }
        for name, data, reason in cases
    ]


def _sdo_exchanges() -> list[dict[str, Any]]:
    """SDO requests and the answers of a freshly booted sensor (every object at its default;
    "" where the sensor sends nothing)."""
    values = sdo.default_values()
    cases: list[tuple[str, bytes]] = []
    for e in OD_ENTRIES:
        cases.append((f"upload_{e.index:04x}_{e.sub}", sdo.upload_request(e.index, e.sub)))
    for e in OD_ENTRIES:
        if e.access == "rw":
            lo, hi = e.limits()
            cases.append((f"download_{e.index:04x}_{e.sub}_default",
                          sdo.download_request(e.index, e.sub, e.default, e.size)))
            if hi < (1 << (8 * e.size)) - 1:
                cases.append((f"download_{e.index:04x}_{e.sub}_too_high",
                              sdo.download_request(e.index, e.sub, hi + 1, e.size)))
            if lo > 0:
                cases.append((f"download_{e.index:04x}_{e.sub}_too_low",
                              sdo.download_request(e.index, e.sub, lo - 1, e.size)))
    hb = (0x1017, 0)
    cases += [
        ("download_read_only_1000", sdo.download_request(0x1000, 0, 1, 4)),
        ("download_const_1018_0", sdo.download_request(0x1018, 0, 4, 1)),
        ("upload_no_object_6000", sdo.upload_request(0x6000, 0)),
        ("upload_no_subindex_1018_9", sdo.upload_request(0x1018, 9)),
        ("download_length_mismatch_1017", sdo.download_request(*hb, 100, 4)),
        ("download_unsized_expedited_1017", bytes([0x22, 0x17, 0x10, 0, 100, 0, 0, 0])),
        ("download_segmented_1017", bytes([0x21, 0x17, 0x10, 0, 2, 0, 0, 0])),
        ("block_upload_1018", bytes([0xA0, 0x18, 0x10, 1, 0, 0, 0, 0])),
        ("unknown_command_e0", bytes([0xE0, 0x00, 0x10, 0, 0, 0, 0, 0])),
        ("client_abort", sdo.abort_frame(0x1017, 0, 0x05040000)),
    ]
    out = []
    for name, request in cases:
        response = sdo.reference_response(request, values)
        out.append({
            "name": name,
            "request": request.hex().upper(),
            "response": response.hex().upper() if response is not None else "",
        })
    return out


def golden_vectors(db: Database | None = None) -> dict[str, Any]:
    """The golden-vector document (for the default node id unless ``db`` is given)."""
    db = db or load_database(c.DEFAULT_NODE_ID)
    vectors = [
        _vector(db, name, encode_command(db, op, counter, **payload))
        for name, op, counter, payload in COMMAND_CASES
    ]
    vectors += [
        _vector(db, name, encode_message(db, msg, sigs)) for name, msg, sigs in MESSAGE_CASES
    ]
    return {
        "format_version": FORMAT_VERSION,
        "generator": "python -m alacs_can golden (can_protocol/generate.sh)",
        "protocol_version": c.PROTOCOL_VERSION,
        "node_id": c.DEFAULT_NODE_ID,
        "byte_order": "little_endian",
        "crc8_j1850": {
            "poly": CRC8_J1850_POLY,
            "init": CRC8_J1850_INIT,
            "xorout": CRC8_J1850_XOROUT,
            "covers_bytes": [0, 6],
            "stored_in_byte": 7,
            "check_input": "123456789",
            "check_value": crc8_j1850(b"123456789"),
        },
        "vectors": vectors,
        "command_checks": _command_checks(db),
        "sdo_exchanges": _sdo_exchanges(),
    }


def _dumps(value: Any, indent: str = "") -> str:
    """JSON with one line per vector signal, so diffs of the committed file stay readable."""
    inner = indent + " "
    if isinstance(value, dict) and value and not all(
        isinstance(v, dict) and "raw" in v for v in value.values()
    ) or (isinstance(value, list) and value and isinstance(value[0], dict)):
        if isinstance(value, list):
            items = [inner + _dumps(v, inner) for v in value]
            return "[\n" + ",\n".join(items) + "\n" + indent + "]"
        items = [f"{inner}{json.dumps(k)}: {_dumps(v, inner)}" for k, v in value.items()]
        return "{\n" + ",\n".join(items) + "\n" + indent + "}"
    if isinstance(value, dict) and value:
        # a "signals" map: one compact line per signal
        items = [f"{inner}{json.dumps(k)}: {json.dumps(v)}" for k, v in value.items()]
        return "{\n" + ",\n".join(items) + "\n" + indent + "}"
    return json.dumps(value)


def golden_json(db: Database | None = None) -> str:
    """The committed text of ``can_protocol/vectors/golden.json``."""
    return _dumps(golden_vectors(db)) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Write the ALACS golden vectors.")
    parser.add_argument("-o", "--output", help="file to write (default: stdout)")
    args = parser.parse_args(argv)
    text = golden_json()
    write_text(text, args.output)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
