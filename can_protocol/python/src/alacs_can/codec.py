"""Encode and decode ALACS frames with cantools; no bus, no clock.

Like libcanard, nothing here owns a socket: callers pass ``can.Message`` objects
in and get ``can.Message`` objects back, so the same code serves SocketCAN, a
replayed log, the virtual bus and tests.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import can
from cantools.database import Database, Message
from cantools.database.namedsignalvalue import NamedSignalValue

from . import constants as c
from .crc import crc8_j1850

Value = int | float | str
"""A decoded signal: number, or the value-table name when choices are decoded."""

COMMAND_DLC = 8
CHECKSUM_BYTE = 7


def _message(db: Database, name: str) -> Message:
    return db.get_message_by_name(name)


def to_can_message(db_msg: Message, data: bytes) -> can.Message:
    return can.Message(
        arbitration_id=db_msg.frame_id,
        is_extended_id=db_msg.is_extended_frame,
        dlc=len(data),
        data=data,
    )


def encode_message(db: Database, name: str, signals: Mapping[str, Any]) -> can.Message:
    """Encode message ``name`` (strict: every signal of the selected mux branch, in range).

    Choice signals accept their value-table name. Raises ``cantools`` EncodeError or
    KeyError. For ALACS_Command use ``encode_command`` so the checksum is filled in.
    """
    msg = _message(db, name)
    return to_can_message(msg, msg.encode(dict(signals), strict=True))


def command_checksum(data: bytes | bytearray) -> int:
    """The CmdChecksum for an 8-byte command: CRC-8/SAE-J1850 over bytes 0..6."""
    return crc8_j1850(bytes(data[:CHECKSUM_BYTE]))


def check_command(data: bytes | bytearray) -> bool:
    """True if ``data`` is 8 bytes long and byte 7 is the CRC-8/SAE-J1850 of bytes 0..6."""
    return len(data) == COMMAND_DLC and command_checksum(data) == data[CHECKSUM_BYTE]


def _opcode(opcode: str | int) -> c.Opcode:
    if isinstance(opcode, str):
        try:
            return c.Opcode[opcode.upper().replace("-", "_")]
        except KeyError:
            raise ValueError(f"unknown opcode {opcode!r}") from None
    return c.Opcode(opcode)


def encode_command(db: Database, opcode: str | int, counter: int, **signals: Any) -> can.Message:
    """Encode an ALACS_Command and fill in CmdChecksum.

    ``opcode`` is an ``Opcode`` or its name (``"LOCALIZE"``); ``counter`` is taken
    modulo 16. ``signals`` are the opcode's payload in physical units, e.g.
    ``LocalizeMode="STOP_AND_GO", TargetId=3, RoughX=-120, RoughY=40, RoughZ=650``.
    For SET_CONFIG, fields left out are sent with their valid bit 0 and their
    minimum value (see ``encode_set_config`` for the friendly form). Raises
    ValueError for an unknown opcode, cantools EncodeError for a missing or
    out-of-range signal.
    """
    op = _opcode(opcode)
    msg = _message(db, c.MSG_COMMAND)
    values: dict[str, Any] = {"CmdOpcode": int(op), "CmdCounter": counter & 0xF, "CmdChecksum": 0}
    if op is c.Opcode.SET_CONFIG:
        page = signals.get("CfgPage", c.CfgPage.ACQUISITION)
        page = c.CfgPage[page] if isinstance(page, str) else c.CfgPage(page)
        values["CfgPage"] = int(page)
        for sig in msg.signals:
            if sig.multiplexer_signal == "CfgPage" and int(page) in (sig.multiplexer_ids or ()):
                values[sig.name] = sig.minimum if sig.minimum is not None else 0
    values.update(signals)
    data = bytearray(msg.encode(values, strict=True))
    data[CHECKSUM_BYTE] = command_checksum(data)
    return to_can_message(msg, bytes(data))


_CFG_FIELDS: dict[str, tuple[c.CfgPage, str, str]] = {
    "exposure_us": (c.CfgPage.ACQUISITION, "CfgExposureUs", "CfgExposureValid"),
    "brce_step": (c.CfgPage.ACQUISITION, "CfgBrceStep", "CfgBrceStepValid"),
    "brce_threshold": (c.CfgPage.ACQUISITION, "CfgBrceThreshold", "CfgBrceThresholdValid"),
    "scan_stops": (c.CfgPage.SCAN, "CfgScanStops", "CfgScanStopsValid"),
    "stop_spacing_mm": (c.CfgPage.SCAN, "CfgStopSpacingMm", "CfgStopSpacingValid"),
    "heartbeat_ms": (c.CfgPage.SCAN, "CfgHeartbeatMs", "CfgHeartbeatValid"),
}
CONFIG_FIELDS = tuple(_CFG_FIELDS)
"""Keyword names accepted by ``encode_set_config``."""


def encode_set_config(
    db: Database, counter: int, **fields: float | None
) -> list[can.Message]:
    """SET_CONFIG frames for the given fields (``exposure_us=800, heartbeat_ms=500``).

    Returns one frame per CfgPage that has a field set, counters ``counter``,
    ``counter+1``... (mod 16). ``None`` values are skipped. Raises ValueError for an
    unknown field or if no field is set.
    """
    per_page: dict[c.CfgPage, dict[str, Any]] = {}
    for key, value in fields.items():
        if key not in _CFG_FIELDS:
            raise ValueError(f"unknown config field {key!r}; expected one of {CONFIG_FIELDS}")
        if value is None:
            continue
        page, sig, valid = _CFG_FIELDS[key]
        per_page.setdefault(page, {})[sig] = value
        per_page[page][valid] = 1
    if not per_page:
        raise ValueError("no config field given")
    return [
        encode_command(db, c.Opcode.SET_CONFIG, counter + i, CfgPage=int(page), **sigs)
        for i, (page, sigs) in enumerate(sorted(per_page.items()))
    ]


def message_name(db: Database, msg: can.Message) -> str | None:
    """Name of the DBC message with ``msg``'s id, or None if the id is not ours."""
    if msg.is_extended_id:
        return None
    try:
        return db.get_message_by_frame_id(msg.arbitration_id).name
    except KeyError:
        return None


def scale_decimals(scale: float) -> int:
    """Decimal places that show every step of ``scale`` (0.1 -> 1, 0.5 -> 1, 1/32767 -> 5,
    20 -> 0): rounding a physical value to them removes binary noise and loses no raw step."""
    if scale >= 1:
        return 0
    return max(0, math.ceil(-math.log10(scale) - 1e-9))


def decode(db: Database, msg: can.Message, choices: bool = True,
           rounded: bool = True) -> dict[str, Value]:
    """Decode ``msg`` into {signal: physical value}.

    With ``choices`` (default), value-table signals are their names (``"LOCALIZE"``)
    and values outside the table stay numbers; otherwise all values are numbers.
    With ``rounded`` (default), scaled values are rounded to their scale's resolution
    (-19.9, not -19.900000000000002), and those of a scale >= 1 are ints. Raises KeyError
    for an id not in ``db`` and cantools DecodeError for a frame that does not fit (short
    DLC, unknown multiplexer value).
    """
    if msg.is_extended_id:
        raise KeyError(f"extended id 0x{msg.arbitration_id:X} is not an ALACS message")
    db_msg = db.get_message_by_frame_id(msg.arbitration_id)
    decoded = db_msg.decode(bytes(msg.data), decode_choices=choices, scaling=True)
    assert isinstance(decoded, dict)  # only container messages decode to a list
    out: dict[str, Value] = {}
    for name, value in decoded.items():
        if isinstance(value, NamedSignalValue):
            out[name] = value.name if choices else int(value.value)
        elif isinstance(value, float) and rounded:
            sig = db_msg.get_signal_by_name(name)
            near = round(value, scale_decimals(sig.scale))
            out[name] = int(near) if sig.scale >= 1 and near.is_integer() else near
        else:
            out[name] = value
    return out


def decode_raw(db: Database, msg: can.Message) -> dict[str, int]:
    """Decode ``msg`` into {signal: raw integer}. Errors as ``decode``."""
    decoded = db.decode_message(
        msg.arbitration_id, bytes(msg.data), decode_choices=False, scaling=False
    )
    assert isinstance(decoded, dict)  # only container messages decode to a list
    return {name: int(value) for name, value in decoded.items()}  # type: ignore[arg-type]


def fault_bits(status: Mapping[str, Value]) -> c.Fault:
    """The Fault flags set in a decoded ALACS_Status."""
    flags = c.Fault(0)
    for flag, sig in c.FAULT_SIGNALS.items():
        if status.get(sig):
            flags |= flag
    return flags
