"""What the mock NDI tracker writes: the TX / BX reply formats (written from the documented
layout, independently of the driver's parser; ``docs/ndi.md``) and the faults that spoil a reply
(:data:`LINK_FAULTS`) or a frame's numbers (:data:`NONFINITE_FAULTS`), with their rates
(:class:`FaultSettings`). :mod:`hexcal.mock_hw.ndi_tracker` re-exports every name."""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hexcal.drivers.crc import crc16, crc16_hex

#: Faults of the reply's bytes (the link).
LINK_FAULTS = ("drop", "garble", "crc", "truncate")
#: Faults of the numbers: a well-formed, CRC-valid reply whose pose record carries NaN or inf:
#: kind -> (field, index in it, value).
NONFINITE_FAULTS: dict[str, tuple[str, int, float]] = {
    "nan": ("position", 0, math.nan),
    "inf": ("position", 2, math.inf),
    "nan_quaternion": ("quaternion", 1, math.nan),
    "inf_rms": ("rms", 0, math.inf),
}
FAULT_KINDS = (*LINK_FAULTS, *NONFINITE_FAULTS)

Sample = tuple[np.ndarray, np.ndarray, float]  # position (3,) mm, quaternion (4,), rms mm


# ------------------------------------------------------------------------------------------------
# Reply formats (written independently of the driver's parser, from the documented format)
# ------------------------------------------------------------------------------------------------
def with_crc(payload: bytes) -> bytes:
    """An ASCII reply: payload, its CRC as 4 uppercase hex digits, CR."""
    return payload + crc16_hex(payload) + b"\r"


def _signed(value: float, resolution: float, digits: int) -> str:
    """Sign + ``digits`` digits of ``value / resolution``; saturates as a fixed field must. A
    non-finite value has no digits: it is spelled as C's printf would, right-aligned in the
    field (``+   nan``), as a glitching firmware might send it."""
    if not math.isfinite(value):
        return ("-" if value < 0 else "+") + str(abs(value)).rjust(digits)
    n = round(value / resolution)
    limit = 10**digits - 1
    n = max(-limit, min(limit, n))
    return ("+" if n >= 0 else "-") + str(abs(n)).zfill(digits)


@dataclass(frozen=True)
class ToolState:
    """What the tracker reports for one port handle in one frame: ``sample`` (position (3,) mm,
    quaternion (4,) scalar first, rms mm) or None when the tool is not seen. ``disabled`` and
    ``unoccupied`` handles have no data; ``with_status`` writes their port status and frame
    number after the word (sawNDITracker's reading) instead of the bare word (ndicapi's)."""

    handle: int
    sample: Sample | None
    port_status: int
    frame: int
    disabled: bool = False
    unoccupied: bool = False
    with_status: bool = False


def format_tx_reply(tools: Sequence[ToolState], system_status: int = 0) -> bytes:
    """The full reply to ``TX:0001`` or ``TX:0801`` (one layout; CRC and CR included)."""
    parts = [f"{len(tools):02X}"]
    for t in tools:
        if t.disabled or t.unoccupied:
            word = "UNOCCUPIED" if t.unoccupied else "DISABLED"
            tail = f"{t.port_status:08X}{t.frame:08X}" if t.with_status else ""
            parts.append(f"{t.handle:02X}{word}{tail}\n")
        elif t.sample is None:
            parts.append(f"{t.handle:02X}MISSING{t.port_status:08X}{t.frame:08X}\n")
        else:
            p, q, rms = t.sample
            parts.append(
                f"{t.handle:02X}"
                + "".join(_signed(float(c), 1e-4, 5) for c in q)
                + "".join(_signed(float(c), 0.01, 6) for c in p)
                + _signed(rms, 1e-4, 5)
                + f"{t.port_status:08X}{t.frame:08X}\n"
            )
    parts.append(f"{system_status:04X}")
    return with_crc("".join(parts).encode("ascii"))


def format_bx_reply(tools: Sequence[ToolState], system_status: int = 0) -> bytes:
    """The full binary reply to ``BX:0001`` or ``BX:0801``: header, header CRC, body, body CRC.
    An unoccupied handle is written as disabled (the BX status byte has no other value for it)."""
    body = bytearray([len(tools)])
    for t in tools:
        if t.disabled or t.unoccupied:
            body += bytes([t.handle, 0x04])
        elif t.sample is None:
            body += bytes([t.handle, 0x02]) + struct.pack("<II", t.port_status, t.frame)
        else:
            p, q, rms = t.sample
            body += bytes([t.handle, 0x01])
            body += struct.pack("<8f", *(float(c) for c in q), *(float(c) for c in p), rms)
            body += struct.pack("<II", t.port_status, t.frame)
    body += struct.pack("<H", system_status)
    header = struct.pack("<HH", 0xA5C4, len(body))
    return header + struct.pack("<H", crc16(header)) + bytes(body) + struct.pack("<H", crc16(body))


@dataclass
class FaultSettings:
    """Random faults on tracking replies (probabilities per reply) and reply timing (s)."""

    drop: float = 0.0
    garble: float = 0.0
    crc: float = 0.0
    truncate: float = 0.0
    nan: float = 0.0  #: per frame: its pose record's position x is NaN (replies CRC-valid)
    delay_s: float = 0.0
    jitter_s: float = 0.0


def _spoiled(sample: Sample, part: str, index: int, value: float) -> Sample:
    """``sample`` with ``value`` (NaN, inf) put into its ``part`` ("position", "quaternion" or
    "rms") at ``index``."""
    p, q, rms = np.array(sample[0], float), np.array(sample[1], float), sample[2]
    if part == "position":
        p[index] = value
    elif part == "quaternion":
        q[index] = value
    else:
        rms = value
    return p, q, rms
