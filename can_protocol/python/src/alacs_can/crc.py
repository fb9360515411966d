"""CRC-8/SAE-J1850 used by ALACS_Command byte 7."""

from __future__ import annotations

from typing import Final

CRC8_J1850_POLY: Final = 0x1D
CRC8_J1850_INIT: Final = 0xFF
CRC8_J1850_XOROUT: Final = 0xFF


def _table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ CRC8_J1850_POLY) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_TABLE: Final = _table()


def crc8_j1850(data: bytes | bytearray | memoryview) -> int:
    """CRC-8/SAE-J1850 (poly 0x1D, init 0xFF, no reflection, xorout 0xFF) of ``data``.

    Known answer: ``crc8_j1850(b"123456789") == 0x4B``.
    """
    crc = CRC8_J1850_INIT
    for byte in bytes(data):
        crc = _TABLE[crc ^ byte]
    return crc ^ CRC8_J1850_XOROUT
