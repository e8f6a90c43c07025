"""CRC-16/ARC, the checksum of the NDI Combined API (Polaris / Aurora class trackers).

Parameters (the catalogue's CRC-16/ARC): width 16, polynomial 0x8005 processed bit-reflected
(0xA001), initial value 0, input and output reflected, no final XOR. The reference check value
(the CRC of ``b"123456789"``) is 0xBB3D.

On the wire the tracker sends an ASCII reply followed by its CRC as 4 uppercase hex digits and a
CR, e.g. ``RESET`` + ``BE6F`` + CR; a host command in the ``NAME:params`` form carries the CRC of
everything before it the same way. Binary (BX) replies carry it as 2 little-endian bytes.
"""

from __future__ import annotations

#: What the functions accept: bytes, bytearray or a byte memoryview.
BytesLike = bytes | bytearray | memoryview

#: CRC-16/ARC of b"123456789" (the catalogue's check value).
CHECK_VALUE = 0xBB3D

_POLY_REFLECTED = 0xA001


def _make_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ _POLY_REFLECTED if crc & 1 else crc >> 1
        table.append(crc)
    return tuple(table)


# One table lookup per byte instead of eight shifts: the reply parser's throughput is bounded
# by this loop, so it is the only place worth the table.
_TABLE = _make_table()


def crc16(data: BytesLike, crc: int = 0) -> int:
    """CRC-16/ARC of ``data`` (bytes-like), continuing from ``crc`` (0 to start)."""
    table = _TABLE
    for b in data:
        crc = (crc >> 8) ^ table[(crc ^ b) & 0xFF]
    return crc


def crc16_hex(data: BytesLike) -> bytes:
    """The CRC of ``data`` as the tracker writes it: 4 uppercase ASCII hex digits."""
    return b"%04X" % crc16(data)


def append_crc(data: bytes) -> bytes:
    """``data`` followed by its CRC in ASCII hex (how a ``NAME:params`` command is sent)."""
    return data + crc16_hex(data)


def check(data: BytesLike, crc_field: bytes | str | int) -> bool:
    """True when ``crc_field`` is the CRC of ``data``.

    ``crc_field`` is the 4 hex digits as sent (bytes or str; uppercase, as the NDI API writes
    them) or an int (the little-endian word of a binary reply). A field that is not 4 uppercase
    hex digits never matches: a garbled CRC field is a corrupt reply, not a parse error.
    """
    if isinstance(crc_field, int):
        return crc16(data) == crc_field
    if isinstance(crc_field, str):
        crc_field = crc_field.encode("ascii", "replace")
    return len(crc_field) == 4 and crc16_hex(data) == bytes(crc_field)
