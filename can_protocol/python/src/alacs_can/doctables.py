"""The generated parts of docs/can-protocol.md: signal tables and value tables.

``python -m alacs_can doc-tables`` prints both sections; paste them over the sections of
the same name. ``tests/test_docs.py`` parses the document on its own and checks it
against the DBC, so a stale paste fails CI.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from enum import IntEnum

from . import constants as c
from .spec import MESSAGES, MessageSpec, SignalSpec

# What each value means, for the value tables. Every value of every DBC value table has
# an entry (test_docs checks the document, which is made from this).
MEANINGS: dict[type[IntEnum], dict[str, str]] = {
    c.Opcode: {
        "LOCALIZE": "localize one apple near `RoughX/Y/Z`",
        "SCAN_ALL": "find every apple in the field of view",
        "HOME": "home the laser slide",
        "STOP": "stop motion, laser off, abort a running scan",
        "SET_CONFIG": "change settings (`CfgPage`)",
        "GET_VERSION": "software and protocol version",
        "CLEAR_FAULT": "clear latched faults, back to IDLE",
    },
    c.AckOpcode: {
        "INVALID": "the command had no known opcode; byte 0 is in `RejectedOpcode`",
    },
    c.ScanMode: {
        "STOP_AND_GO": "the slide stops at each stop while the camera exposes",
        "CONTINUOUS": "the camera exposes while the slide moves",
    },
    c.CfgPage: {
        "ACQUISITION": "exposure and bRCE settings",
        "SCAN": "scan stops, stop spacing, heartbeat",
    },
    c.AckResult: {
        "ACK": "accepted",
        "NACK": "rejected; `NackReason` (and `NackDetail`) say why",
        "DONE": "a long command (HOME) has finished",
    },
    c.NackReason: {
        "NONE": "not a NACK",
        "BAD_DLC": "command frame DLC ≠ 8",
        "BAD_CHECKSUM": "byte 7 is not the CRC-8/SAE-J1850 of bytes 0..6",
        "BAD_COUNTER": "same counter as the last accepted command, within 1 s",
        "UNKNOWN_OPCODE": "byte 0 is not 1..7",
        "BUSY": "a scan or homing is running",
        "NOT_HOMED": "LOCALIZE/SCAN_ALL before a successful HOME",
        "NOT_CALIBRATED": "no valid camera/laser calibration",
        "OUT_OF_RANGE": "rough position outside the working envelope; `NackDetail` says "
                        "which limit",
        "FAULT_ACTIVE": "a latched fault (Status `Fault*`); send CLEAR_FAULT; also the late "
                        "NACK of a failed HOME",
        "NMT_NOT_OPERATIONAL": "NMT state is not OPERATIONAL (send NMT START)",
        "BAD_VALUE": "a field is outside its range (e.g. `CfgBrceStep` = 0); `NackDetail` "
                     "names it",
        "INTERNAL": "internal error",
    },
    c.NackDetail: {
        "NONE": "no detail (not a NACK, or the reason says it all); value and limit 0",
        "STROKE": "the slide position the target needs (mm from home) is outside the "
                  "stroke; limit: the stroke end it passed (0 or `motion.stroke_mm`)",
        "DEPTH": "rough z (mm) outside the working depth; limit: 500 or 2000",
        "LATERAL": "rough x (mm) outside the lateral range at its depth; limit: the "
                   "range's edge at that depth (see Working envelope)",
        "FRAME": "the target's window in the image is too small (the rough position is at "
                 "or beyond the image edge); value: its smaller side in px, limit: 16 px",
        "CROSS_FIELD": "the fields are valid one by one but not together or with the "
                       "current settings; value and limit 0",
        "SPACING_X_STOPS": "(stops − 1) × stop spacing exceeds the stroke; value: that "
                           "span (mm), limit: the stroke (mm)",
        "MODE": "`LocalizeMode`/`ScanAllMode`/`CfgPage` outside its table; value: the "
                "received number, limit: the largest valid one",
        "EXPOSURE": "`CfgExposureUs` refused; value and limit in ms (exposure at most half "
                    "of `laser.max_on_ms`)",
        "BRCE_STEP": "`CfgBrceStep` outside 1..15; value and limit: steps",
        "SCAN_STOPS": "`CfgScanStops` outside 1..15; value and limit: stops",
        "STOP_SPACING": "`CfgStopSpacingMm` outside what the daemon accepts (0.5..50 mm); "
                        "value and limit: mm",
        "HEARTBEAT": "`CfgHeartbeatMs` refused; value and limit: ms",
    },
    c.ResultStatus: {
        "MEASURED": "a measurement: the objects' pages are fitted positions",
        "NOT_FOUND": "nothing found; `ObjectCount` 0",
        "ROUGH_ONLY": "the rough position echoed back with the default diameter: **never a "
                      "measurement**; one object, `LinesUsed` 0",
        "FAILED": "the scan could not be completed (fault); `ObjectCount` 0",
        "ABORTED": "the scan was stopped (STOP, NMT, shutdown); `ObjectCount` 0",
        "AMBIGUOUS": "a fit that is more likely another object than the target (far from the rough "
                     "position, or two objects explain the lines alike); one object: the best guess, "
                     "its σ wide enough to cover the other and a confidence below 50 %",
    },
    c.ResultReason: {
        "NONE": "MEASURED (no reason needed)",
        "NO_LINES_IN_GATE": "no laser line fell within the gate around the rough position",
        "TOO_FEW_LINES": "lines were found but too few (or too short) to fit a sphere",
        "FIT_FAILED": "the fit found no sphere of an apple's size in the points",
        "TWO_SURFACES": "two objects (the target and a neighbour or a leaf) explain the lines about "
                        "equally well (AMBIGUOUS)",
        "FAR_FROM_ROUGH": "what the lines saw lies farther from the rough position than the RGB-D "
                          "camera's error makes likely: more likely a neighbour. ROUGH_ONLY: the rough "
                          "position goes out in its place (`scan.rough_when_far_from_rough`, the "
                          "default), unless the points off that object, fitted again round the rough "
                          "position, give a fruit on three lines or more that is likelier the target, "
                          "which then goes out as any fit does (MEASURED, without this reason); "
                          "AMBIGUOUS: the fit goes out (a fruit the widened search found "
                          "where the gate saw nothing else, or with that option off)",
        "CAMERA_FAULT": "camera timeout or corrupt frames",
        "MOTION_FAULT": "slide fault (limit hit, homing lost)",
        "LASER_FAULT": "laser on-time limit hit",
        "STOPPED": "STOP command or NMT stop",
        "SHUTDOWN": "alacsd was shutting down or resetting",
        "INTERNAL": "internal error",
        "OUTSIDE_GATE": "MEASURED, but found by the widened search outside the gate around the "
                        "rough position: check it is the fruit you meant (confidence is capped)",
        "BRIGHT_AMBIENT": "NOT_FOUND: no stop found a laser line (none in the gate, none beyond it), "
                          "and the metering found the ambient light bright (direct sun: its red "
                          "grows by `metering.bright_dn_per_ms` or more): the line is most likely "
                          "too weak against sunlit skin. Shade the fruit, scan again when the sun is "
                          "off it, or fit the laser's band-pass filter",
    },
    c.ResultMode: {
        "LOCALIZE": "the result of a LOCALIZE",
        "SCAN_ALL": "the result of a SCAN_ALL",
    },
    c.ProgressPhase: {
        "MOVING": "the slide moves to the next stop",
        "EXPOSING": "the camera exposes at a stop, or meters the light (laser off, stop 0): before a "
                    "stop-and-go scan's first move, or in a continuous scan while the slide runs up to its "
                    "first stop",
        "FITTING": "the lines are being fitted",
        "SECOND_PASS": "the second pass (follow-up stops) runs",
    },
    c.ObjPage: {
        "CENTER": "`CenterX/Y/Z`",
        "APPROACH_POINT": "`ApproachX/Y/Z`",
        "QUALITY": "`SigmaMm`, `Confidence`, `DiameterMm`, `OcclusionPct`, `LinesUsed`, "
                   "`PointsUsed`",
        "APPROACH_NORMAL": "`NormalX/Y/Z`",
    },
    c.SensorState: {
        "BOOT": "starting",
        "HOMING": "homing the slide",
        "IDLE": "ready",
        "SCANNING": "a LOCALIZE or SCAN_ALL runs",
        "FAULT": "a latched fault; CLEAR_FAULT",
        "STOPPED": "after STOP; CLEAR_FAULT",
    },
    c.NmtCommand: {
        "START": "to OPERATIONAL",
        "STOP": "to STOPPED (only NMT and heartbeat)",
        "PRE_OPERATIONAL": "to PRE_OPERATIONAL",
        "RESET_NODE": "restart alacsd",
        "RESET_COMM": "restart alacsd's CAN side",
    },
    c.NmtState: {
        "BOOTUP": "boot-up message (sent once after power-up or reset)",
        "STOPPED": "NMT STOPPED",
        "OPERATIONAL": "NMT OPERATIONAL: commands accepted",
        "PRE_OPERATIONAL": "NMT PRE_OPERATIONAL: SDO, STOP and GET_VERSION only",
    },
    c.EmcyErrorCode: {
        "NO_ERROR": "all faults cleared",
        "GENERIC": "STOP_REQUESTED",
        "HARDWARE": "camera faults",
        "SOFTWARE_INTERNAL": "INTERNAL",
        "DATA_SET": "CONFIG_INVALID, NOT_CALIBRATED",
        "MONITORING": "LASER_OVERTIME",
        "CAN_OVERRUN": "CAN_TX_OVERFLOW",
        "CAN_BUS_OFF_RECOVERED": "CAN_BUS_OFF (sent once the bus is back)",
        "DEVICE_SPECIFIC": "HOMING_TIMEOUT, LIMIT_HIT",
    },
    c.EmcyReason: {
        "NONE": "all faults cleared",
        **{f.name: f"fault bit {f.bit_length() - 1} raised" for f in c.Fault
           if f.name is not None},
    },
    c.SdoClientCommand: {
        "DOWNLOAD_4B": "expedited download, 4 bytes",
        "DOWNLOAD_3B": "expedited download, 3 bytes",
        "DOWNLOAD_2B": "expedited download, 2 bytes",
        "DOWNLOAD_1B": "expedited download, 1 byte",
        "UPLOAD_REQUEST": "upload request",
        "ABORT": "client abort",
    },
    c.SdoServerCommand: {
        "UPLOAD_4B": "upload response, 4 bytes",
        "UPLOAD_3B": "upload response, 3 bytes",
        "UPLOAD_2B": "upload response, 2 bytes",
        "UPLOAD_1B": "upload response, 1 byte",
        "DOWNLOAD_RESPONSE": "download confirmed",
        "ABORT": "abort; `SdoTxData` is the abort code",
    },
}


def _meaning(table: type[IntEnum], name: str) -> str:
    if table is c.AckOpcode and name != "INVALID":
        return MEANINGS[c.Opcode][name]
    return MEANINGS[table][name]


def _type(sig: SignalSpec) -> str:
    return f"{'s' if sig.signed else 'u'}{sig.length}"


def _num(v: float) -> str:
    if v == 1 / 32767:
        return "1/32767"
    v = round(v, 9)
    return str(int(v)) if float(v).is_integer() else repr(v)


def _present(msg: MessageSpec, sig: SignalSpec) -> str:
    if sig.mux is None:
        return "always (mux)" if sig.is_multiplexer else "always"
    mux_sig = msg.signal(sig.mux[0])
    assert mux_sig.choices is not None
    names = [mux_sig.choices(v).name for v in sig.mux_values()]
    text = f"{sig.mux[0]} = {' / '.join(str(n) for n in names)}"
    return text + " (mux)" if sig.is_multiplexer else text


def _bits(sig: SignalSpec) -> str:
    end = sig.start + sig.length - 1
    return str(sig.start) if end == sig.start else f"{sig.start}..{end}"


_DOC_ORDER = (c.MSG_COMMAND, c.MSG_ACK, c.MSG_RESULT_HEADER, c.MSG_RESULT_OBJECT,
              c.MSG_PROGRESS, c.MSG_STATUS, c.MSG_NMT, c.MSG_HEARTBEAT, c.MSG_EMCY, c.MSG_SDO_TX,
              c.MSG_SDO_RX)
_HEX = {c.EmcyErrorCode: 4, c.SdoClientCommand: 2, c.SdoServerCommand: 2}


def _value(table: type[IntEnum], v: IntEnum) -> str:
    digits = _HEX.get(table)
    return f"0x{int(v):0{digits}X}" if digits else str(int(v))


def _messages() -> list[MessageSpec]:
    by_name = {m.name: m for m in MESSAGES}
    assert set(_DOC_ORDER) == set(by_name)
    return [by_name[n] for n in _DOC_ORDER]


def signal_tables() -> str:
    """The '## Messages and signals' tables, one per message."""
    out: list[str] = []
    for msg in _messages():
        out += [f"### {msg.name}", "",
                "| Signal | Bits | Type | Scale | Unit | Range | Present when | Meaning |",
                "|---|---|---|---|---|---|---|---|"]
        for sig in msg.signals:
            lo, hi = sig.phys_range()
            meaning = sig.comment
            if sig.choices is not None:
                meaning += " " + ", ".join(f"{_value(sig.choices, v)} {v.name}"
                                           for v in sig.choices) + "."
            out.append(f"| `{sig.name}` | {_bits(sig)} | {_type(sig)} | {_num(sig.scale)} | "
                       f"{sig.unit} | {_num(lo)}..{_num(hi)} | {_present(msg, sig)} | "
                       f"{meaning} |")
        out.append("")
    return "\n".join(out)


def value_tables() -> str:
    """The '## Value tables' section: one table per value table, every value."""
    users: dict[type[IntEnum], list[str]] = {}
    for msg in _messages():
        for sig in msg.signals:
            if sig.choices is not None:
                users.setdefault(sig.choices, []).append(f"{msg.name}.{sig.name}")
    out: list[str] = []
    for table, sigs in users.items():
        out += [f"#### {', '.join(f'`{s}`' for s in sigs)}", "",
                "| Value | Name | Meaning |", "|---|---|---|"]
        for v in table:
            out.append(f"| {_value(table, v)} | {v.name} | {_meaning(table, v.name)} |")
        out.append("")
    return "\n".join(out)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Print the generated tables of "
                                                 "docs/can-protocol.md.")
    parser.add_argument("what", choices=["signals", "values"])
    args = parser.parse_args(argv)
    sys.stdout.write(signal_tables() if args.what == "signals" else value_tables())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
