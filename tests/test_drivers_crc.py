"""CRC-16/ARC: the catalogue check value, the NDI API's known strings, and a bitwise reference."""

from __future__ import annotations

import numpy as np
import pytest

from hexcal.drivers.crc import CHECK_VALUE, append_crc, check, crc16, crc16_hex


def _bitwise(data: bytes) -> int:
    """The definition, one bit at a time (reflected poly 0xA001, init 0, no final XOR)."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def test_catalogue_check_value():
    assert CHECK_VALUE == 0xBB3D
    assert crc16(b"123456789") == 0xBB3D


@pytest.mark.parametrize(
    "text, crc",
    [
        (b"RESET", b"BE6F"),  # the reply to a BREAK: RESETBE6F
        (b"INIT:", b"E3A5"),  # ndicapi's probe sends INIT:E3A5
        (b"", b"0000"),
    ],
)
def test_ndi_known_strings(text, crc):
    assert crc16_hex(text) == crc
    assert check(text, crc) and check(text, crc.decode())


def test_table_matches_the_bitwise_definition():
    rng = np.random.default_rng(0)
    for n in (1, 2, 7, 64, 300):
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        assert crc16(data) == _bitwise(data)
        assert crc16(bytearray(data)) == crc16(memoryview(data)) == crc16(data)


def test_incremental_and_append():
    assert crc16(b"56789", crc16(b"1234")) == CHECK_VALUE
    assert append_crc(b"RESET") == b"RESETBE6F"


def test_check_rejects_wrong_or_garbled_fields():
    assert not check(b"RESET", b"BE6E")
    assert not check(b"RESET", b"be6f")  # the API writes uppercase: anything else is corrupt
    assert not check(b"RESET", b"BE6")
    assert not check(b"RESET", "G#6F")
    assert check(b"RESET", 0xBE6F) and not check(b"RESET", 0xBE6E)


def test_every_single_byte_error_is_detected():
    payload = bytearray(
        b"0101+10000+00000+00000+00000+000000+000000+020000+00100000000310000002A\n0000"
    )
    crc = crc16(payload)
    for i in range(len(payload)):
        for flip in (0x01, 0x80, 0x20):
            corrupt = bytearray(payload)
            corrupt[i] ^= flip
            assert crc16(corrupt) != crc
