from __future__ import annotations

import pytest

from alacs_can import crc8_j1850


def _bitwise(data: bytes) -> int:
    crc = 0xFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


def test_known_answer() -> None:
    # CRC catalogue entry CRC-8/SAE-J1850: check = 0x4B, residue = 0xC4.
    assert crc8_j1850(b"123456789") == 0x4B


def test_empty_input_is_init_xor_out() -> None:
    assert crc8_j1850(b"") == 0x00


@pytest.mark.parametrize(
    "data",
    [b"\x00", b"\xff" * 7, bytes(range(7)), b"\x01\x01\x03\x88\xdf\x02\x41", bytes(range(256))],
)
def test_table_matches_bitwise_reference(data: bytes) -> None:
    assert crc8_j1850(data) == _bitwise(data)


def test_accepts_bytearray_and_memoryview() -> None:
    assert crc8_j1850(bytearray(b"123456789")) == crc8_j1850(memoryview(b"123456789")) == 0x4B


def test_residue() -> None:
    # Running the CRC over data + its CRC leaves the catalogue residue 0xC4 in the register.
    data = b"123456789"
    assert crc8_j1850(data + bytes([crc8_j1850(data)])) ^ 0xFF == 0xC4
