"""Expedited SDO (CiA 301) frames for the sensor's object dictionary, and the reference
server behaviour the golden vectors (and through them alacsd's C++ server) follow.

Only expedited transfers exist here: every object is at most 4 bytes.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from dataclasses import dataclass

from .constants import SdoAbort
from .spec import OD_ENTRIES, OdEntry

_CCS_DOWNLOAD = 1
_CCS_UPLOAD = 2
_CCS_ABORT = 4


def upload_request(index: int, sub: int) -> bytes:
    """SDO_Rx payload asking for the value of ``index``/``sub``."""
    return struct.pack("<BHBI", 0x40, index, sub, 0)


def download_request(index: int, sub: int, value: int, size: int) -> bytes:
    """SDO_Rx payload writing ``value`` (``size`` = 1, 2 or 4 bytes) expedited, size given."""
    if size not in (1, 2, 4):
        raise ValueError("expedited size must be 1, 2 or 4")
    cmd = 0x23 | ((4 - size) << 2)
    return struct.pack("<BHBI", cmd, index, sub, value & ((1 << (8 * size)) - 1))


def abort_frame(index: int, sub: int, code: int) -> bytes:
    return struct.pack("<BHBI", 0x80, index, sub, code)


@dataclass(frozen=True)
class SdoResponse:
    """A decoded SDO_Tx payload."""

    command: int
    index: int
    sub: int
    data: int

    @property
    def aborted(self) -> bool:
        return self.command == 0x80

    @property
    def abort(self) -> SdoAbort | None:
        return SdoAbort(self.data) if self.aborted else None

    def value(self) -> int:
        """The uploaded value, masked to the size the server indicated."""
        size = 4 - ((self.command >> 2) & 3) if self.command & 0x01 else 4
        return self.data & ((1 << (8 * size)) - 1)


def parse_response(data: bytes) -> SdoResponse:
    if len(data) != 8:
        raise ValueError(f"SDO frames have 8 bytes, got {len(data)}")
    cmd, index, sub, value = struct.unpack("<BHBI", bytes(data))
    return SdoResponse(cmd, index, sub, value)


def _find(index: int, sub: int) -> tuple[OdEntry | None, bool]:
    """(entry, index exists)."""
    exists = False
    for e in OD_ENTRIES:
        if e.index == index:
            exists = True
            if e.sub == sub:
                return e, True
    return None, exists


def reference_response(request: bytes, values: Mapping[tuple[int, int], int]) -> bytes | None:
    """What the sensor answers to ``request`` when its objects hold ``values``.

    ``values`` maps (index, sub) to the current value of every readable entry. Writes
    are checked (access, size, the entry's limits) but not applied. Returns None when
    the request needs no answer (a client abort). This is the behaviour golden.json
    records and the C++ server is tested against; settings the daemon itself refuses
    (VALUE_RANGE, DEVICE_STATE) are beyond it.
    """
    if len(request) != 8:
        return None
    cmd, index, sub, data = struct.unpack("<BHBI", bytes(request))
    ccs = cmd >> 5

    def abort(code: SdoAbort) -> bytes:
        return abort_frame(index, sub, int(code))

    if ccs == _CCS_ABORT:
        return None
    if ccs not in (_CCS_DOWNLOAD, _CCS_UPLOAD):
        return abort(SdoAbort.UNKNOWN_COMMAND)
    entry, index_exists = _find(index, sub)
    if entry is None:
        return abort(SdoAbort.NO_SUBINDEX if index_exists else SdoAbort.NO_OBJECT)
    if ccs == _CCS_UPLOAD:
        value = values[(index, sub)]
        return struct.pack("<BHBI", 0x43 | ((4 - entry.size) << 2), index, sub, value)
    expedited, sized = bool(cmd & 0x02), bool(cmd & 0x01)
    if not expedited:
        return abort(SdoAbort.UNKNOWN_COMMAND)
    if entry.access != "rw":
        return abort(SdoAbort.READ_ONLY)
    if sized and 4 - ((cmd >> 2) & 3) != entry.size:
        return abort(SdoAbort.LENGTH_MISMATCH)
    value = data & ((1 << (8 * entry.size)) - 1)
    lo, hi = entry.limits()
    if value > hi:
        return abort(SdoAbort.VALUE_TOO_HIGH)
    if value < lo:
        return abort(SdoAbort.VALUE_TOO_LOW)
    return struct.pack("<BHBI", 0x60, index, sub, 0)


def default_values() -> dict[tuple[int, int], int]:
    """Every entry at its EDS default value (a freshly booted sensor, no faults)."""
    return {(e.index, e.sub): e.default for e in OD_ENTRIES}
