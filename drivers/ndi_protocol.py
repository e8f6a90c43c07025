"""NDI Combined API replies: CRC-checked payloads, the errors a reply raises, and the TX / BX /
PHSR parsers that turn a reply into a :class:`TrackerFrame` of :class:`ToolReport` records. The
reply layouts are in ``docs/ndi.md`` ("How the driver talks to the tracker");
:mod:`hexcal.drivers.ndi` re-exports every public name."""

from __future__ import annotations

import math
import re
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from hexcal.acquire.acquisition import TrackerSample
from hexcal.drivers.crc import crc16, crc16_hex
from hexcal.drivers.ndi_codes import (
    BX_DISABLED,
    BX_MISSING,
    BX_START,
    BX_VALID,
    ERROR_HINT,
    ERROR_TEXT,
    MAX_POSITION_MM,
    PORT_FAULT_BITS,
    PORT_OUT_OF_VOLUME,
    PORT_PARTIALLY_IN_VOLUME,
    QUATERNION_NORM_TOLERANCE,
    SYSTEM_FAULT_BITS,
    SYSTEM_STATUS_BITS,
    SYSTEM_STATUS_HINT,
)
from hexcal.errors import DeviceError

# The records of a TX:0001 (or 0801) reply, exactly as specified (fullmatch: nothing more,
# nothing less). DISABLED and UNOCCUPIED come bare or followed by port status and frame number:
# ndicapi.cxx's ndiTXHelper reads status and frame after DISABLED when the line goes on and
# skips the bare word UNOCCUPIED; sawNDITracker's mtsNDISerial::Track skips status and frame
# after both words.
_TX_POSE = re.compile(
    rb"([0-9A-F]{2})([+-]\d{5})([+-]\d{5})([+-]\d{5})([+-]\d{5})"
    rb"([+-]\d{6})([+-]\d{6})([+-]\d{6})([+-]\d{5})([0-9A-F]{8})([0-9A-F]{8})"
)
_TX_MISSING = re.compile(rb"([0-9A-F]{2})MISSING([0-9A-F]{8})([0-9A-F]{8})")
_TX_DISABLED = re.compile(rb"([0-9A-F]{2})DISABLED(?:([0-9A-F]{8})([0-9A-F]{8}))?")
_TX_UNOCCUPIED = re.compile(rb"([0-9A-F]{2})UNOCCUPIED(?:([0-9A-F]{8})([0-9A-F]{8}))?")
_HEX2 = re.compile(rb"[0-9A-F]{2}")
_HEX4 = re.compile(rb"[0-9A-F]{4}")
_PHSR = re.compile(rb"([0-9A-F]{2})((?:[0-9A-F]{5})*)")


# ------------------------------------------------------------------------------------------------
# Errors
# ------------------------------------------------------------------------------------------------
class TrackerError(DeviceError):
    """Something went wrong talking to the tracker; the message names the port and says what to
    do. ``port`` is the port URL."""

    def __init__(self, message: str, port: str = ""):
        super().__init__(message)
        self.port = port


class TrackerCRCError(TrackerError):
    """A reply failed its CRC (garbled bytes, line noise, a wrong baud rate): it was discarded."""


class TrackerFormatError(TrackerError):
    """A reply passed its CRC but does not follow the documented format: it was discarded."""


class TrackerTimeout(TrackerError):
    """No complete reply in time. ``partial`` holds what did arrive (empty when nothing did)."""

    def __init__(self, message: str, port: str = "", partial: bytes = b""):
        super().__init__(message, port)
        self.partial = partial


class TrackerReplyError(TrackerError):
    """The tracker answered ``ERRORxx``: ``code`` (int) to ``command`` (str)."""

    def __init__(self, message: str, port: str = "", code: int = 0, command: str = ""):
        super().__init__(message, port)
        self.code = code
        self.command = command


class TrackerDisconnected(TrackerError):
    """The port is gone (cable unplugged, adapter removed, tracker off) or cannot be opened."""


def error_text(code: int) -> str:
    """The NDI meaning of an ``ERRORxx`` code, with a hint for the common ones."""
    text = ERROR_TEXT.get(code, "unknown error code (see the NDI API guide)")
    hint = ERROR_HINT.get(code)
    return f"{text}; {hint}" if hint else text


def _preview(data: bytes, limit: int = 48) -> str:
    shown = repr(bytes(data[:limit]))
    return shown + (f"... ({len(data)} bytes)" if len(data) > limit else "")


_NOISE_ADVICE = (
    "the reading was discarded. An occasional one is line noise; if they are frequent, check the "
    "cable (shielded, short, away from motor power) and try a lower baud rate"
)


def _crc_error(port: str, command: str, reply: bytes, why: str) -> TrackerCRCError:
    return TrackerCRCError(
        f"corrupt reply from the tracker on {port} to {command!r}: {why} in {_preview(reply)}; "
        f"{_NOISE_ADVICE}",
        port,
    )


def _format_error(port: str, command: str, reply: bytes, why: str) -> TrackerFormatError:
    return TrackerFormatError(
        f"unexpected reply from the tracker on {port} to {command!r}: {why} in {_preview(reply)}; "
        "the reading was discarded. Check that the device is an NDI Combined API tracker and that "
        "nothing else talks to it on this port",
        port,
    )


def _reply_error(payload: bytes, port: str, command: str) -> TrackerReplyError:
    code_text = payload[5:7]
    code = int(code_text, 16) if _HEX2.fullmatch(code_text) else -1
    return TrackerReplyError(
        f"the tracker on {port} refused {command!r}: {payload[:7].decode('ascii', 'replace')} "
        f"({error_text(code)})",
        port,
        code,
        command,
    )


def checked_payload(reply: bytes, port: str = "", command: str = "") -> bytes:
    """The payload of an ASCII reply (with or without its final CR) once its CRC is checked.

    Raises :class:`TrackerCRCError` when the CRC does not match (or the reply is too short to
    carry one) and :class:`TrackerReplyError` for an ``ERRORxx`` reply.
    """
    body = reply[:-1] if reply[-1:] == b"\r" else reply
    if len(body) < 5:
        raise _crc_error(port, command, reply, "too short to carry a CRC")
    payload, crc_field = body[:-4], body[-4:]
    expected = crc16_hex(payload)
    if crc_field != expected:
        raise _crc_error(
            port,
            command,
            reply,
            f"CRC mismatch (the reply says {crc_field.decode('ascii', 'replace')!r}, "
            f"its content gives {expected.decode()!r})",
        )
    if payload[:5] == b"ERROR":
        raise _reply_error(payload, port, command)
    return payload


def build_command(command: str) -> bytes:
    """The bytes to send for ``command``: ``NAME:params`` gets its CRC appended, then CR."""
    data = command.encode("ascii")
    if b":" in data:
        data += crc16_hex(data)
    return data + b"\r"


# ------------------------------------------------------------------------------------------------
# Frames
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class ToolReport:
    """One port handle in one tracker frame.

    ``state`` is ``"ok"`` (pose present), ``"missing"`` (the tracker does not see the tool),
    ``"disabled"``, or ``"invalid"`` (the tracker sent a pose record with a number no pose can
    have: ``defect`` says which, e.g. "non-finite position (x = nan)"). ``position`` (3,) mm
    and ``quaternion`` (4,) unit, scalar first, are None unless ``ok`` (then every number is
    finite); ``rms_mm`` is the tracker's RMS marker fit error (mm, NaN unless ``ok``).
    ``port_status`` is the bit field of :data:`PORT_STATUS_BITS`; ``frame_number`` the
    tracker's frame counter (None when not reported). A pose whose port status carries one of
    :data:`PORT_FAULT_BITS` is still ``ok`` (the numbers are there), but :meth:`problem` refuses
    it, naming the bits.
    """

    handle: int
    state: Literal["ok", "missing", "disabled", "invalid"]
    position: np.ndarray | None = None
    quaternion: np.ndarray | None = None
    rms_mm: float = math.nan
    port_status: int = 0
    frame_number: int | None = None
    defect: str = ""

    @property
    def visible(self) -> bool:
        return self.state == "ok"

    @property
    def out_of_volume(self) -> bool:
        """The tool is outside the tracker's characterised measurement volume."""
        return bool(self.port_status & PORT_OUT_OF_VOLUME)

    @property
    def partially_out_of_volume(self) -> bool:
        """Some of the tool's markers are outside the characterised volume."""
        return bool(self.port_status & PORT_PARTIALLY_IN_VOLUME)

    @property
    def port_faults(self) -> list[str]:
        """The names of the :data:`PORT_FAULT_BITS` set in :attr:`port_status` (bits 8-15)."""
        return [name for bit, (name, _) in PORT_FAULT_BITS.items() if self.port_status & bit]

    def _fault_bits_text(self) -> tuple[str, str]:
        """(names, what to do) of the port status fault bits set, or ("", "")."""
        set_bits = [(n, h) for bit, (n, h) in PORT_FAULT_BITS.items() if self.port_status & bit]
        names = ", ".join(n for n, _ in set_bits)
        hints = "; ".join(dict.fromkeys(h for _, h in set_bits))
        return names, hints

    def problem(self, port: str = "", accept_out_of_volume: bool = False) -> str | None:
        """A sentence for the operator when this tool's reading must not be used, else None."""
        where = f"the tracker on {port}" if port else "the tracker"
        names, hints = self._fault_bits_text()
        if self.state == "missing":
            cause = f": {names}" if names else ""
            if self.out_of_volume:
                advice = (
                    "It is outside the characterised measurement volume: move the tool back into "
                    "the volume"
                )
            else:
                advice = (
                    "Clear the line of sight between the camera and the tool's markers, or bring "
                    "the tool back into the measurement volume"
                )
            return (
                f"tool {self.handle:02X} MISSING: {where} does not see it (port status "
                f"{self.port_status:08X}{cause}). {advice}" + (f"; {hints}" if hints else "")
            )
        if self.state == "disabled":
            return f"tool {self.handle:02X} is DISABLED on {where}: run setup_tools() to enable it"
        if self.state == "invalid":
            frame = "" if self.frame_number is None else f"tracker frame {self.frame_number}: "
            return (
                f"{frame}{self.defect} of tool {self.handle:02X} from {where}: a number no pose "
                "can have, in a reply that passed its CRC, so that reading was discarded. An "
                "occasional one is a tracker glitch; if it repeats, power-cycle the tracker and "
                "check its firmware"
            )
        problems = []
        if names:
            problems.append(
                f"tool {self.handle:02X} from {where}: port status {self.port_status:08X} reports "
                f"{names}, so that pose was refused. {hints[:1].upper()}{hints[1:]}"
            )
        if not accept_out_of_volume and (self.out_of_volume or self.partially_out_of_volume):
            part = "partly " if not self.out_of_volume else ""
            at = ""
            if self.position is not None:
                x, y, z = (float(c) for c in self.position)
                at = f"at ({x:.1f}, {y:.1f}, {z:.1f}) mm in the tracker's frame; "
            problems.append(
                f"tool {self.handle:02X} is {part}outside the characterised measurement volume "
                f"of {where} ({at}port status {self.port_status:08X}): its pose is not within "
                "the stated accuracy. Move the tool back into the volume (move the robot or the "
                "tracker so that the tool stays inside it)"
            )
        return "; ".join(problems) or None


@dataclass(frozen=True, slots=True)
class UnoccupiedPort:
    """A port handle the tracker reported ``UNOCCUPIED`` in a frame: nothing is plugged into
    that port any more. ``port_status`` and ``frame_number`` are those the record carried
    (0 and None for the bare word)."""

    handle: int
    port_status: int = 0
    frame_number: int | None = None

    def problem(self, port: str = "") -> str:
        """What the operator reads when this handle's pose is asked for."""
        where = f"the tracker on {port}" if port else "the tracker"
        return (
            f"tool {self.handle:02X} is UNOCCUPIED on {where}: nothing is plugged into its port "
            "any more (the tool was unplugged or its cable came loose). Plug it back in, then "
            "run setup_tools() (or reconnect())"
        )


@dataclass(frozen=True, slots=True)
class TrackerFrame:
    """One reply to TX (or BX): every reported handle, the system status, and when it came.

    ``tools`` are the handles with data (a pose, MISSING, DISABLED or an invalid record);
    ``unoccupied`` the handles reported UNOCCUPIED (nothing in that port), which have none.
    ``received_at`` is the host's ``time.monotonic()`` (s) when the reply's last byte arrived;
    ``latency_s`` the time from sending the command to that moment (NaN when parsed offline).
    ``port`` names the port the frame came from (used in messages). ``measured_at`` is the host
    time (``time.monotonic()`` s) at which the tracker measured this frame, as the driver's
    :class:`FrameClock` estimates it from the frame number, and ``timing_uncertainty_s`` the
    half-width (s) of the interval it is known to lie in (both NaN when parsed offline).
    """

    tools: tuple[ToolReport, ...]
    system_status: int
    received_at: float = math.nan
    latency_s: float = math.nan
    port: str = ""
    measured_at: float = math.nan
    timing_uncertainty_s: float = math.nan
    unoccupied: tuple[UnoccupiedPort, ...] = ()

    @property
    def t(self) -> float:
        """The frame's time stamp (monotonic s): ``measured_at`` when known, else
        ``received_at``."""
        return self.measured_at if math.isfinite(self.measured_at) else self.received_at

    @property
    def frame_number(self) -> int | None:
        """The tracker's frame counter (the largest reported by any handle), or None."""
        numbers = [t.frame_number for t in self.tools] + [u.frame_number for u in self.unoccupied]
        known = [n for n in numbers if n is not None]
        return max(known) if known else None

    def tool(self, handle: int | None = None) -> ToolReport:
        """The report of ``handle`` (the first handle when None). KeyError, with a sentence for
        the operator, when the frame has no data for it (absent, or UNOCCUPIED)."""
        if handle is not None:
            for t in self.tools:
                if t.handle == handle:
                    return t
            for u in self.unoccupied:
                if u.handle == handle:
                    raise KeyError(u.problem(self.port))
        elif self.tools:
            return self.tools[0]
        if not self.tools:
            empty = "".join(f"; {u.problem(self.port)}" for u in self.unoccupied)
            raise KeyError(f"the frame from {self.port or 'the tracker'} reports no tool{empty}")
        have = ", ".join(f"{t.handle:02X}" for t in self.tools)
        raise KeyError(
            f"the frame from {self.port or 'the tracker'} has no handle {handle:02X} (has {have})"
        )

    def system_problems(self, mask: int = 0xFFFF) -> list[str]:
        """The system status bits set (within ``mask``), as sentences (with what to do for the
        faults)."""
        status = self.system_status & mask
        out = []
        for bit, text in SYSTEM_STATUS_BITS.items():
            if status & bit:
                hint = SYSTEM_STATUS_HINT.get(bit)
                out.append(
                    f"system status {self.system_status:04X} of the tracker on {self.port}: "
                    f"{text}" + (f"; {hint}" if hint else "")
                )
        reserved = status & ~sum(SYSTEM_STATUS_BITS)
        if reserved:
            out.append(
                f"system status {self.system_status:04X} of the tracker on {self.port}: reserved "
                f"bits {reserved:04X} set (not in the current API guide)"
            )
        return out

    def to_sample(
        self, handle: int | None = None, accept_out_of_volume: bool = False
    ) -> TrackerSample:
        """The :class:`~hexcal.acquire.acquisition.TrackerSample` of ``handle``: a pose, or a fault,
        stamped :attr:`t` (the frame's measurement instant when the driver estimated it). A pose
        with a fault (port status fault bits, out of volume, a system fault) keeps its numbers
        in the sample, as raw data; the fault refuses it."""
        try:
            tool = self.tool(handle)
        except KeyError as exc:
            return TrackerSample(self.t, None, None, fault=str(exc.args[0]))
        faults = [p for p in (tool.problem(self.port, accept_out_of_volume),) if p]
        faults += self.system_problems(SYSTEM_FAULT_BITS)
        if not tool.visible:
            return TrackerSample(self.t, None, None, fault="; ".join(faults))
        return TrackerSample(
            self.t,
            tool.position,
            tool.quaternion,
            tool.rms_mm,
            fault="; ".join(faults) or None,
            t_uncertainty_s=self.timing_uncertainty_s,
        )


def _nonfinite(v: float) -> bool:
    return not math.isfinite(v)


def _values(names: str, values: tuple[float, ...], bad: Callable[[float], bool]) -> str:
    """``"x = nan, z = inf"``: the named values for which ``bad`` holds."""
    return ", ".join(f"{n} = {v:.6g}" for n, v in zip(names.split(), values, strict=True) if bad(v))


def pose_defect(
    position: tuple[float, float, float],
    quaternion: tuple[float, float, float, float],
    rms_mm: float,
) -> str | None:
    """What makes a reported pose record unusable as numbers, or None: NaN or infinity in the
    ``position`` (mm), the ``quaternion`` or the ``rms_mm``, or a position coordinate beyond
    :data:`MAX_POSITION_MM`. (A finite quaternion of the wrong norm is a format error,
    :func:`parse_tx_reply`.)"""
    defects = []
    if not all(map(math.isfinite, position)):
        defects.append(f"non-finite position ({_values('x y z', position, _nonfinite)})")
    elif max(map(abs, position)) > MAX_POSITION_MM:
        far = _values("x y z", position, lambda v: abs(v) > MAX_POSITION_MM)
        defects.append(f"implausible position ({far} mm, beyond +-{MAX_POSITION_MM:g} mm)")
    if not all(map(math.isfinite, quaternion)):
        defects.append(f"non-finite quaternion ({_values('q0 qx qy qz', quaternion, _nonfinite)})")
    if not math.isfinite(rms_mm):
        defects.append(f"non-finite RMS error ({rms_mm})")
    return "; ".join(defects) or None


def _pose_report(
    handle: int,
    q: tuple[float, float, float, float],
    p: tuple[float, float, float],
    rms_mm: float,
    status: int,
    frame: int,
    port: str,
    command: str,
    reply: bytes,
) -> ToolReport:
    """The report of one pose record: ``ok``, or ``invalid`` when a number is unusable."""
    defect = pose_defect(p, q, rms_mm)
    if defect is not None:
        return ToolReport(handle, "invalid", port_status=status, frame_number=frame, defect=defect)
    return ToolReport(
        handle,
        "ok",
        np.array(p, float),
        _unit_quaternion(q, port, command, reply),
        float(rms_mm),
        status,
        frame,
    )


def _unit_quaternion(
    q: tuple[float, float, float, float], port: str, command: str, reply: bytes
) -> np.ndarray:
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise _format_error(port, command, reply, f"quaternion norm {norm:.5f} is not 1")
    return np.array((q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm))


def parse_tx_reply(
    reply: bytes,
    received_at: float = math.nan,
    *,
    port: str = "",
    command: str = "TX:0001",
    latency_s: float = math.nan,
) -> TrackerFrame:
    """Parse a reply to ``TX:0001`` or ``TX:0801`` (one layout, in docs/ndi.md), CRC
    checked.

    ``reply`` is the whole reply, CRC included, with or without its final CR. Raises
    :class:`TrackerCRCError`, :class:`TrackerReplyError` (``ERRORxx``) or
    :class:`TrackerFormatError`; never returns a frame built from a reply that failed a check.
    """
    payload = checked_payload(reply, port, command)
    records = payload[2:].split(b"\n")
    count = payload[:2]
    if not _HEX2.fullmatch(count):
        raise _format_error(port, command, reply, f"handle count {count!r} is not 2 hex digits")
    if len(records) != int(count, 16) + 1:
        raise _format_error(
            port,
            command,
            reply,
            f"{int(count, 16)} handles announced, {len(records) - 1} records sent",
        )
    tools = []
    unoccupied: list[UnoccupiedPort] = []
    for rec in records[:-1]:
        m = _TX_POSE.fullmatch(rec)
        if m is not None:
            h, q0, qx, qy, qz, x, y, z, err, status, frame = m.groups()
            tools.append(
                _pose_report(
                    int(h, 16),
                    (int(q0) * 1e-4, int(qx) * 1e-4, int(qy) * 1e-4, int(qz) * 1e-4),
                    (int(x) * 0.01, int(y) * 0.01, int(z) * 0.01),
                    int(err) * 1e-4,
                    int(status, 16),
                    int(frame, 16),
                    port,
                    command,
                    reply,
                )
            )
            continue
        m = _TX_MISSING.fullmatch(rec)
        if m is not None:
            h, status, frame = m.groups()
            tools.append(
                ToolReport(
                    int(h, 16), "missing", port_status=int(status, 16), frame_number=int(frame, 16)
                )
            )
            continue
        m = _TX_DISABLED.fullmatch(rec)
        if m is not None:
            h, status, frame = m.groups()
            tools.append(
                ToolReport(
                    int(h, 16),
                    "disabled",
                    port_status=int(status, 16) if status else 0,
                    frame_number=int(frame, 16) if frame else None,
                )
            )
            continue
        m = _TX_UNOCCUPIED.fullmatch(rec)
        if m is not None:
            # Nothing in that port: no data, but the other handles' records stand.
            h, status, frame = m.groups()
            unoccupied.append(
                UnoccupiedPort(
                    int(h, 16),
                    int(status, 16) if status else 0,
                    int(frame, 16) if frame else None,
                )
            )
            continue
        raise _format_error(
            port,
            command,
            reply,
            f"handle record {bytes(rec)!r} is not a pose, MISSING, DISABLED or UNOCCUPIED",
        )
    status = records[-1]
    if not _HEX4.fullmatch(status):
        raise _format_error(
            port, command, reply, f"system status {bytes(status)!r} is not 4 hex digits"
        )
    return TrackerFrame(
        tuple(tools), int(status, 16), received_at, latency_s, port, unoccupied=tuple(unoccupied)
    )


def parse_bx_reply(
    reply: bytes,
    received_at: float = math.nan,
    *,
    port: str = "",
    command: str = "BX:0001",
    latency_s: float = math.nan,
) -> TrackerFrame:
    """Parse a binary reply to ``BX:0001`` or ``BX:0801`` (one layout, in docs/ndi.md),
    both CRCs checked.

    An ASCII reply (``ERRORxx``) raises :class:`TrackerReplyError`; otherwise as
    :func:`parse_tx_reply`.
    """
    if reply[:2] != BX_START:
        if reply[-1:] == b"\r":
            checked_payload(reply, port, command)  # raises on ERRORxx or a bad CRC
        raise _crc_error(port, command, reply, "no binary start sequence C4 A5")
    if len(reply) < 8:
        raise _crc_error(port, command, reply, "binary reply cut short")
    length, header_crc = struct.unpack_from("<HH", reply, 2)
    if crc16(reply[:4]) != header_crc:
        raise _crc_error(port, command, reply, "header CRC mismatch")
    if len(reply) != 6 + length + 2:
        raise _crc_error(
            port, command, reply, f"header announces {length} body bytes, {len(reply) - 8} arrived"
        )
    body = reply[6 : 6 + length]
    if crc16(body) != struct.unpack_from("<H", reply, 6 + length)[0]:
        raise _crc_error(port, command, reply, "body CRC mismatch")
    tools = []
    try:
        pos = 1
        for _ in range(body[0]):
            handle, state = body[pos], body[pos + 1]
            pos += 2
            if state == BX_DISABLED:
                tools.append(ToolReport(handle, "disabled"))
                continue
            if state == BX_VALID:
                q0, qx, qy, qz, x, y, z, err = struct.unpack_from("<8f", body, pos)
                pos += 32
                status, frame = struct.unpack_from("<II", body, pos)
                pos += 8
                tools.append(
                    _pose_report(
                        handle,
                        (q0, qx, qy, qz),
                        (x, y, z),
                        err,
                        status,
                        frame,
                        port,
                        command,
                        reply,
                    )
                )
            elif state == BX_MISSING:
                status, frame = struct.unpack_from("<II", body, pos)
                pos += 8
                tools.append(ToolReport(handle, "missing", port_status=status, frame_number=frame))
            else:
                raise _format_error(
                    port, command, reply, f"handle {handle:02X} has status byte {state:02X}"
                )
        (system_status,) = struct.unpack_from("<H", body, pos)
        pos += 2
    except (IndexError, struct.error):
        raise _format_error(port, command, reply, "body shorter than its handle records") from None
    if pos != len(body):
        raise _format_error(
            port, command, reply, f"{len(body) - pos} unexpected bytes after the system status"
        )
    return TrackerFrame(tuple(tools), system_status, received_at, latency_s, port)


def parse_phsr_reply(
    payload: bytes, port: str = "", command: str = "PHSR"
) -> list[tuple[int, int]]:
    """(handle, handle status) pairs of a checked PHSR payload."""
    m = _PHSR.fullmatch(payload)
    if m is None or len(m.group(2)) != 5 * int(m.group(1), 16):
        raise _format_error(port, command, payload, "not a PHSR handle list")
    entries = m.group(2)
    return [
        (int(entries[i : i + 2], 16), int(entries[i + 2 : i + 5], 16))
        for i in range(0, len(entries), 5)
    ]
