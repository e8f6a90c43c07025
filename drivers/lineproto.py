"""A plain-text line protocol for pose trackers that do not speak the NDI API (laser trackers,
motion-capture bridges, a script on another machine): one pose per line.

Format
------
ASCII text, one record per line, ending in LF (a CR before it is ignored)::

    # anything after '#' is a comment; blank lines are ignored
    t x y z qw qx qy qz [rms]
    MISSING t

- ``t``: the tracker's own timestamp, s (any origin);
- ``x y z``: tool position in the tracker frame, mm;
- ``qw qx qy qz``: tool orientation, unit quaternion, scalar first. It is renormalised; a norm
  further than 1e-3 from 1 is refused (a wrong column order, not rounding);
- ``rms``: optional fit error of the pose, mm (>= 0);
- ``MISSING t``: the tracker could not measure the tool at time ``t``.

Fields are separated by spaces or tabs; numbers use the decimal syntax of Python floats
(``1``, ``-0.25``, ``1e-3``); ``nan`` and ``inf`` are refused. Example::

    # hexapod platform tool, tracker frame
    12.500 0.013 -0.004 200.002 1 0 0 0 0.011
    12.525 0.010 -0.001 199.998 0.99999 0.0001 0 0
    MISSING 12.550

:class:`LineTracker` reads such a stream from any pyserial port (``serial_for_url``: a device,
``socket://host:port``, ``loop://`` in tests) and stamps each record with the host's
``time.monotonic()`` on arrival. A line that breaks the format raises
:class:`LineProtocolError` (a :class:`~hexcal.drivers.ndi_protocol.TrackerFormatError`), naming the
source and line number; it is never turned into a pose.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import serial

from hexcal.acquire.acquisition import TrackerSample
from hexcal.drivers.base import SERIAL_IO_ERRORS, SerialDevice
from hexcal.drivers.limits import check_duration
from hexcal.drivers.ndi_protocol import TrackerDisconnected, TrackerFormatError, TrackerTimeout

#: Longest line accepted (bytes): a stream without newlines is not this protocol.
MAX_LINE = 1024
QUATERNION_NORM_TOLERANCE = 1e-3
FORMAT = "t x y z qw qx qy qz [rms]"

_IO_ERRORS = SERIAL_IO_ERRORS
#: What opening the port may raise: a bad URL or setting, or the OS refusing the device.
_OPEN_ERRORS: tuple[type[BaseException], ...] = (ValueError, *_IO_ERRORS)


class LineProtocolError(TrackerFormatError, ValueError):
    """A line that does not follow the format; ``lineno`` and ``line`` say which."""

    def __init__(self, message: str, source: str = "", lineno: int | None = None, line: str = ""):
        super().__init__(message, source)
        self.lineno = lineno
        self.line = line


@dataclass(frozen=True)
class LinePose:
    """One record: the tracker's time ``t`` (s), ``position`` (3,) mm and ``quaternion`` (4,)
    unit scalar first (both None when the tool was MISSING), ``rms_mm`` (NaN when not sent),
    ``received_at`` (host monotonic s, NaN when parsed offline) and the line number."""

    t: float
    position: np.ndarray | None
    quaternion: np.ndarray | None
    rms_mm: float = math.nan
    received_at: float = math.nan
    lineno: int | None = None

    @property
    def missing(self) -> bool:
        return self.position is None


def _where(source: str, lineno: int | None) -> str:
    where = f"line {lineno}" if lineno is not None else "line"
    return f"{where} from {source}" if source else where


def _number(text: str, name: str, raw: str, source: str, lineno: int | None) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
        ok = False
    else:
        ok = math.isfinite(value)
    if not ok:
        raise LineProtocolError(
            f"{_where(source, lineno)}: {name} = {text!r} is not a finite number in {raw!r} "
            f"(expected '{FORMAT}' or 'MISSING t')",
            source,
            lineno,
            raw,
        )
    return value


def parse_line(
    line: str | bytes, lineno: int | None = None, source: str = "", received_at: float = math.nan
) -> LinePose | None:
    """The record on ``line``, or None for a blank or comment line. Raises
    :class:`LineProtocolError` naming ``source`` and ``lineno``."""
    if isinstance(line, bytes):
        data = line
        try:
            line = data.decode("ascii")
        except UnicodeDecodeError:
            raise LineProtocolError(
                f"{_where(source, lineno)}: not ASCII text ({data[:60]!r}); check the baud rate and "
                "that the device sends this line protocol",
                source,
                lineno,
                data.decode("ascii", "replace"),
            ) from None
    raw = line.rstrip("\r\n")
    fields = raw.split("#", 1)[0].split()
    if not fields:
        return None
    if fields[0] == "MISSING":
        if len(fields) != 2:
            raise LineProtocolError(
                f"{_where(source, lineno)}: 'MISSING' takes exactly one field, the time t: {raw!r}",
                source,
                lineno,
                raw,
            )
        t = _number(fields[1], "t", raw, source, lineno)
        return LinePose(t, None, None, math.nan, received_at, lineno)
    if len(fields) not in (8, 9):
        raise LineProtocolError(
            f"{_where(source, lineno)}: expected '{FORMAT}' (8 or 9 numbers) or 'MISSING t', got "
            f"{len(fields)} fields: {raw!r}",
            source,
            lineno,
            raw,
        )
    names = ("t", "x", "y", "z", "qw", "qx", "qy", "qz", "rms")
    v = [_number(f, n, raw, source, lineno) for f, n in zip(fields, names, strict=False)]
    q = np.array(v[4:8])
    norm = math.hypot(*v[4:8])  # scaled: huge components give their norm, not an overflow
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        shown = f"{norm:.6f}" if norm < 1e6 else f"{norm:.6g}"  # not 300 digits
        raise LineProtocolError(
            f"{_where(source, lineno)}: the quaternion (qw qx qy qz) has norm {shown}, not 1: "
            f"wrong column order or units? {raw!r}",
            source,
            lineno,
            raw,
        )
    rms = v[8] if len(v) == 9 else math.nan
    if rms < 0:
        raise LineProtocolError(
            f"{_where(source, lineno)}: rms = {rms} is negative: {raw!r}", source, lineno, raw
        )
    return LinePose(v[0], np.array(v[1:4]), q / norm, rms, received_at, lineno)


def parse_lines(lines: Iterable[str | bytes], source: str = "") -> Iterator[LinePose]:
    """The records of ``lines`` (numbered from 1), skipping blanks and comments."""
    for n, line in enumerate(lines, start=1):
        rec = parse_line(line, n, source)
        if rec is not None:
            yield rec


def format_pose(
    t: float, position: Sequence[float], quaternion: Sequence[float], rms_mm: float | None = None
) -> str:
    """One record line (with LF): ``t`` s, ``position`` (3,) mm, ``quaternion`` (4,) scalar
    first, optional ``rms_mm``. 9 significant digits: far below any tracker's noise."""
    values = [t, *position, *quaternion] + ([rms_mm] if rms_mm is not None else [])
    return " ".join(f"{float(v):.9g}" for v in values) + "\n"


def format_missing(t: float) -> str:
    """A MISSING record line (with LF)."""
    return f"MISSING {float(t):.9g}\n"


class LineTracker(SerialDevice):
    """Reads the line protocol from a pyserial port (``url`` for :func:`serial.serial_for_url`).

    :meth:`read_pose` returns the next record; :meth:`sample` the next one as a
    :class:`~hexcal.acquire.acquisition.TrackerSample` (the acquisition's PoseSource; MISSING becomes a
    fault sample). ``timeout`` (s, finite, > 0 and at most
    :data:`~hexcal.drivers.limits.MAX_TIMEOUT_S`, else ValueError) bounds the wait for one line.
    """

    def __init__(self, url: str, baudrate: int = 115200, timeout: float = 1.0):
        self.url = url
        self.baudrate = baudrate
        self.timeout = check_duration("timeout", timeout)
        self.port: serial.Serial | None = None
        self.lineno = 0
        self._buf = bytearray()

    def open(self) -> LineTracker:
        self.close()
        try:
            self.port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=0.02)
        except _OPEN_ERRORS as exc:
            raise TrackerDisconnected(
                f"cannot open the tracker port {self.url}: {exc}. Check the port name and that the "
                "device is connected",
                self.url,
            ) from exc
        self.lineno = 0
        self._buf.clear()
        return self

    def close(self) -> None:
        self._close_port()

    def read_line(self) -> tuple[bytes, float]:
        """The next raw line (without LF) and its host arrival time (monotonic s)."""
        if self.port is None:
            raise TrackerDisconnected(
                f"the tracker on {self.url} is not open: call open() first", self.url
            )
        deadline = time.monotonic() + self.timeout
        try:
            while True:
                end = self._buf.find(b"\n")
                if end >= 0:
                    line = bytes(self._buf[:end])
                    del self._buf[: end + 1]
                    self.lineno += 1
                    return line, time.monotonic()
                if len(self._buf) > MAX_LINE:
                    junk = bytes(self._buf[:60])
                    self._buf.clear()
                    raise LineProtocolError(
                        f"{self.url}: more than {MAX_LINE} bytes without a newline ({junk!r}...): check "
                        "the baud rate and that the device sends this line protocol",
                        self.url,
                        self.lineno + 1,
                    )
                chunk = self.port.read(max(1, self.port.in_waiting))
                self._buf += chunk
                if not chunk and time.monotonic() >= deadline:
                    partial = (
                        f" (an unfinished line is waiting: {bytes(self._buf[:60])!r})"
                        if self._buf
                        else ""
                    )
                    raise TrackerTimeout(
                        f"no complete line from the tracker on {self.url} within {self.timeout:g} s{partial}: "
                        "check that it is switched on, connected and streaming",
                        self.url,
                        bytes(self._buf),
                    )
        except _IO_ERRORS as exc:
            self.close()
            raise TrackerDisconnected(
                f"lost the connection to the tracker on {self.url} ({exc}): plug it back in, then open() again",
                self.url,
            ) from exc

    def read_pose(self) -> LinePose:
        """The next record (comments and blank lines skipped)."""
        while True:
            line, t = self.read_line()
            rec = parse_line(line, self.lineno, self.url, received_at=t)
            if rec is not None:
                return rec

    def sample(self) -> TrackerSample:
        """The next record as a TrackerSample stamped on arrival; MISSING gives a fault sample."""
        rec = self.read_pose()
        if rec.missing:
            return TrackerSample(
                rec.received_at,
                None,
                None,
                fault=f"the tracker on {self.url} reports the tool MISSING at t = {rec.t:g} s (line "
                f"{rec.lineno}): clear its line of sight",
            )
        return TrackerSample(rec.received_at, rec.position, rec.quaternion, rec.rms_mm)
