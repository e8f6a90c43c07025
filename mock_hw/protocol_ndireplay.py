"""pyserial URL handler for ``ndireplay://PATH``: a serial port that replays a capture of real
traffic, recorded with pyserial's standard ``spy://`` handler, to the driver.

Record (no code needed: the driver opens any pyserial URL)::

    NDITracker("spy:///dev/ttyUSB0?file=capture.txt", ...)

then replay the capture, with no tracker attached::

    NDITracker("ndireplay:///abs/path/capture.txt", ...)   # relative: ndireplay://capture.txt

``PATH`` is taken literally (no percent-decoding, as ``spy://`` writes it) up to an optional
``?``; the handler takes no options. pyserial imports this module once ``hexcal.mock_hw`` is in
``serial.protocol_handler_packages``, which importing :mod:`hexcal.mock_hw` arranges.

The capture format is spy's hexdump (``serial.urlhandler.protocol_spy.FormatHexdump``), one
record per line::

    000003.001 TX   0000  48 45 4C 4C 4F                                    HELLO

timestamp (s), label padded to 4 characters, then for TX / RX a hex row offset, two spaces and a
row of up to 16 bytes (``XX `` each, one extra space after the 8th), a space and an ASCII column.
The bytes are read from the hex columns by position, never from the ASCII column (which shows
the same bytes as text, so a reply such as ``0A 0D`` looks like hex there). Consecutive rows of
one direction make one chunk. Control records (``Q-RX``, ``Q-TX``, ``BRK``, ``RTS``, ``DTR``,
``CTS``, ``DSR``, ``RI``, ``CD``) and ``RX <empty>`` are skipped: a replay has no line, so flushes,
BREAKs, modem lines and baud-rate changes (which spy does not record at all) are accepted and
ignored. A colour capture (``spy://...&color``) is read too; a ``&raw`` capture is not.

What the replay checks, and how it behaves:

- ``write(data)`` must be the next bytes the capture's TX records expect, byte for byte, else
  :class:`ReplayDivergence` names the capture file, the line of the first differing byte, the
  bytes expected and the bytes sent; a write after the last TX record raises
  :class:`ReplayDivergence` ("capture ... ends at line N; the driver sent more: ..."). A failed
  write consumes nothing.
- ``read(size)`` returns RX bytes only once every TX recorded before them has been written
  (causality: a tracker answers only what it was sent). Otherwise it waits until the port's
  ``timeout``, as a real port does when no reply comes, and returns what it has (maybe ``b""``).
  ``in_waiting`` counts the RX bytes available that way.
- Every ``open()`` replays from the capture's start (spy also starts a new capture, truncating
  the file, each time a port is opened). The capture is parsed at open: a missing file or a
  malformed line raises :class:`serial.SerialException` naming the file (and the line).

A replay reproduces bytes, not timing: replies arrive as soon as they are causally due, so a
capture in which a reply came late or was cut off by a timeout replays as a prompt reply.
"""

from __future__ import annotations

import bisect
import re
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import serial
from serial.serialutil import SerialException

from hexcal.mock_hw.serial_port import MockSerialBase

if TYPE_CHECKING:
    from typing_extensions import Buffer

URL_SCHEME = "ndireplay"

#: spy's labels for control calls (``FormatHexdump.control``): no bytes on the line.
CONTROL_LABELS = frozenset({"Q-RX", "Q-TX", "BRK", "RTS", "DTR", "CTS", "DSR", "RI", "CD"})
ROW_BYTES = 16  # bytes per hexdump row
_HEX_FIELD_WIDTH = 3 * ROW_BYTES + 1  # "XX " per byte and the extra space after the 8th

# spy: '{:010.3f} {:4} {}{}' = timestamp, space, label padded to 4, space, the rest.
_RECORD = re.compile(r"(?P<ts>\d+\.\d{3}) (?P<label>[^ ]{1,4}) {0,3}(?: (?P<rest>.*))?\Z")
_OFFSET = re.compile(r"(?P<offset>[0-9A-F]{4,8})  ")
_HEX_BYTE = re.compile(r"[0-9A-F]{2}")
_COLOUR = re.compile(r"(?:\x1b\[[0-9;]*m)+")  # spy's &color prefixes records with SGR codes
_SHOWN = 32  # bytes of data shown in a divergence message before "..."


class CaptureError(SerialException):
    """A capture that cannot be replayed: missing, unreadable or malformed."""


class ReplayDivergence(SerialException):
    """The driver sent something other than what the capture recorded next."""


@dataclass(frozen=True)
class CaptureChunk:
    """Consecutive bytes in one direction: ``TX`` host to device, ``RX`` device to host.

    ``rows`` maps the chunk to the capture: (index in ``data`` of a row's first byte, the
    row's 1-based line number in the capture), in order.
    """

    direction: Literal["TX", "RX"]
    data: bytes
    rows: tuple[tuple[int, int], ...]

    def line_at(self, index: int) -> int:
        """The capture line holding byte ``index`` of :attr:`data`."""
        starts = [start for start, _ in self.rows]
        return self.rows[max(bisect.bisect_right(starts, index) - 1, 0)][1]

    @property
    def last_line(self) -> int:
        return self.rows[-1][1]


def parse_hex_row(field: str) -> bytes:
    """The bytes of one hexdump row's hex field (the text after the offset and its two spaces;
    anything past the field's 49 columns, i.e. the ASCII column, is ignored).

    Byte ``i`` sits at column ``3 * i`` (plus one from the 9th byte on); the row ends at the
    first blank cell, and everything after it must be blank. Raises ValueError with the reason.
    """
    field = field[:_HEX_FIELD_WIDTH]
    out = bytearray()
    for i in range(ROW_BYTES):
        col = 3 * i + (1 if i >= 8 else 0)
        cell = field[col : col + 2]
        if not cell.strip():
            if field[col:].strip():
                raise ValueError(
                    f"hex column {i + 1} is blank but more follows: {field[col:].strip()!r}"
                )
            break
        if not _HEX_BYTE.fullmatch(cell) or field[col + 2 : col + 3] not in ("", " "):
            raise ValueError(
                f"hex column {i + 1} is {field[col : col + 3]!r}, not 2 uppercase hex digits"
            )
        if i == 8 and field[col - 1 : col] != " ":  # the extra space after the 8th byte
            raise ValueError("no double space between the 8th and 9th byte")
        out.append(int(cell, 16))
    if not out:
        raise ValueError("a TX/RX row without bytes")
    return bytes(out)


def parse_capture(text: str, source: str = "<capture>") -> list[CaptureChunk]:
    """The TX and RX chunks of a spy hexdump capture, in order (format: module docstring).

    Rows of one direction that follow each other (control records in between are skipped)
    merge into one chunk. ``source`` names the capture in errors. Raises :class:`CaptureError`
    naming ``source`` and the line for a line that is not a spy record.
    """
    chunks: list[CaptureChunk] = []
    data = bytearray()
    rows: list[tuple[int, int]] = []
    direction: Literal["TX", "RX"] | None = None
    prev: tuple[str, int, int] | None = None  # last data row: direction, offset, length

    def bad(lineno: int, line: str, reason: str) -> CaptureError:
        return CaptureError(
            f"capture {source}, line {lineno}: {reason}: {line[:100]!r}. Expected a pyserial "
            "spy:// hexdump record, e.g. '000003.001 TX   0000  48 45 4C 4C 4F ...  HELLO' "
            "(a capture made with spy's '&raw' option cannot be replayed)"
        )

    def flush() -> None:
        if direction is not None and data:
            chunks.append(CaptureChunk(direction, bytes(data), tuple(rows)))

    # split("\n"), not splitlines(): line numbers must be those an editor shows.
    for lineno, raw in enumerate(text.split("\n"), start=1):
        line = _COLOUR.sub("", raw.rstrip("\r"))
        if not line.strip():
            continue
        m = _RECORD.match(line)
        if m is None:
            raise bad(lineno, line, "not 'timestamp label ...'")
        label, rest = m["label"], m["rest"] or ""
        if label in CONTROL_LABELS:
            continue
        if label not in ("TX", "RX"):
            known = ", ".join(sorted(CONTROL_LABELS))
            raise bad(lineno, line, f"unknown label {label!r} (TX, RX or a control: {known})")
        if rest.strip() == "<empty>":  # spy's '&all' logs reads that returned nothing
            continue
        mo = _OFFSET.match(rest)
        if mo is None:
            raise bad(lineno, line, "no hex row offset (4 hex digits and two spaces)")
        offset = int(mo["offset"], 16)
        try:
            row = parse_hex_row(rest[mo.end() :])
        except ValueError as exc:
            raise bad(lineno, line, str(exc)) from None
        # A row that continues a record (offset > 0) must follow that record's full previous
        # row: this catches lines deleted or reordered by hand.
        if offset and prev != (label, offset - ROW_BYTES, ROW_BYTES):
            raise bad(
                lineno, line, f"row offset {offset:04X} does not continue the previous {label} row"
            )
        prev = (label, offset, len(row))
        if label != direction:
            flush()
            data, rows = bytearray(), []
            direction = "TX" if label == "TX" else "RX"  # the label is one of them (above)
        rows.append((len(data), lineno))
        data += row
    flush()
    return chunks


def load_capture(path: str) -> list[CaptureChunk]:
    """:func:`parse_capture` of the file at ``path``; :class:`CaptureError` when it is
    missing, unreadable or not ASCII."""
    try:
        with open(path, "rb") as f:
            blob = f.read()
    except OSError as exc:
        raise CaptureError(f"cannot read the capture {path!r}: {exc.strerror or exc}") from None
    try:
        text = blob.decode("ascii")
    except UnicodeDecodeError as exc:
        lineno = blob.count(b"\n", 0, exc.start) + 1
        raise CaptureError(
            f"capture {path}, line {lineno}: byte {blob[exc.start]:#04x} is not ASCII; a spy "
            "hexdump is plain ASCII"
        ) from None
    return parse_capture(text, path)


def capture_path(url: str) -> str:
    """The capture file an ``ndireplay://`` URL names. Raises :class:`SerialException`."""
    scheme, sep, rest = url.partition("://")
    if scheme.lower() != URL_SCHEME or not sep:
        raise SerialException(f"{url!r} is not an {URL_SCHEME}:// URL")
    path, _, query = rest.partition("?")
    if query:
        raise SerialException(
            f"{URL_SCHEME}:// takes no options ({url!r}): use {URL_SCHEME}://PATH, "
            f"{URL_SCHEME}:///abs/path for an absolute path"
        )
    if not path:
        raise SerialException(f"{url!r} names no capture file: use {URL_SCHEME}:///abs/path")
    return path


def _shown(data: bytes) -> str:
    return repr(data[:_SHOWN]) + (f"... ({len(data)} bytes)" if len(data) > _SHOWN else "")


class Serial(MockSerialBase):
    """A pyserial port that replays a spy capture (see the module docstring)."""

    BAUDRATES = (9600, 14400, 19200, 38400, 57600, 115200, 921600, 1228739)

    def __init__(self, *args, **kwargs):
        self._path = ""
        self._chunks: list[CaptureChunk] = []
        self._cond = threading.Condition()  # guards the cursors; a write wakes a waiting read
        self._tx = (0, 0)  # (chunk index, byte) of the next TX byte expected
        self._rx = (0, 0)  # (chunk index, byte) of the next RX byte to deliver
        super().__init__(*args, **kwargs)

    # -- open / close ---------------------------------------------------------------------------
    def open(self) -> None:
        port = self._port_to_open()
        path = capture_path(port)
        chunks = load_capture(path)
        with self._cond:
            self._path, self._chunks = path, chunks
            self._tx = (self._next(0, "TX"), 0)
            self._rx = (self._next(0, "RX"), 0)
        self._reconfigure_port()
        self.is_open = True

    def close(self) -> None:
        self.is_open = False
        super().close()

    def _check_open(self) -> None:
        self._line_check()

    # -- the capture ----------------------------------------------------------------------------
    def _next(self, index: int, direction: str) -> int:
        """The first chunk at or after ``index`` going ``direction`` (len(chunks) if none)."""
        while index < len(self._chunks) and self._chunks[index].direction != direction:
            index += 1
        return index

    def _available_locked(self) -> int:
        """RX bytes whose preceding TX has all been written and that are not read yet."""
        index, byte = self._rx
        frontier = self._tx[0]  # the first TX chunk not fully written
        total = 0
        for chunk in self._chunks[index:frontier]:
            if chunk.direction == "RX":
                total += len(chunk.data)
        return max(total - byte, 0)

    def _last_line(self) -> int:
        return self._chunks[-1].last_line if self._chunks else 0

    @property
    def tx_remaining(self) -> int:
        """Bytes the capture still expects the driver to send."""
        with self._cond:
            index, byte = self._tx
            return sum(len(c.data) for c in self._chunks[index:] if c.direction == "TX") - byte

    @property
    def rx_remaining(self) -> int:
        """Bytes of the capture's replies not read yet (available now or later)."""
        with self._cond:
            index, byte = self._rx
            return sum(len(c.data) for c in self._chunks[index:] if c.direction == "RX") - byte

    # -- data -----------------------------------------------------------------------------------
    @property
    def in_waiting(self) -> int:
        self._check_open()
        with self._cond:
            return self._available_locked()

    def read(self, size: int = 1) -> bytes:
        """Up to ``size`` bytes, waiting up to ``timeout`` s (None: forever) for all of them."""
        self._check_open()
        timeout = self.timeout
        deadline = None if timeout is None else time.monotonic() + timeout
        out = bytearray()
        with self._cond:
            while True:
                while len(out) < size and self._available_locked():
                    index, byte = self._rx
                    chunk = self._chunks[index]
                    piece = chunk.data[byte : byte + size - len(out)]
                    out += piece
                    byte += len(piece)
                    if byte == len(chunk.data):
                        self._rx = (self._next(index + 1, "RX"), 0)
                    else:
                        self._rx = (index, byte)
                if len(out) >= size:
                    return bytes(out)
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return bytes(out)
                # Only a write (from another thread) can make more due: wait as a real port
                # waits for a reply that may never come.
                self._cond.wait(remaining)

    def write(self, data: Buffer) -> int:
        """Accept ``data`` if it is what the capture's TX records expect next, else raise
        :class:`ReplayDivergence` (nothing of ``data`` is consumed then)."""
        self._check_open()
        data = bytes(data)
        with self._cond:
            index, byte = self._tx
            pos = 0
            while pos < len(data):
                if index >= len(self._chunks):
                    raise ReplayDivergence(
                        f"capture {self._path} ends at line {self._last_line()}; the driver sent "
                        f"more: {_shown(data[pos:])}"
                        + (f" (in its write of {_shown(data)})" if pos else "")
                    )
                chunk = self._chunks[index]
                n = min(len(chunk.data) - byte, len(data) - pos)
                if chunk.data[byte : byte + n] != data[pos : pos + n]:
                    k = next(
                        i for i in range(n) if chunk.data[byte + i] != data[pos + i]
                    )  # the first differing byte names the line
                    raise ReplayDivergence(
                        "the driver's traffic diverged from the capture at line "
                        f"{chunk.line_at(byte + k)} of {self._path}: the capture expects the "
                        f"driver to send {_shown(chunk.data[byte:])}, the driver sent "
                        f"{_shown(data)}"
                    )
                pos += n
                byte += n
                if byte == len(chunk.data):
                    # A write may run on past a reply (the driver sent its next command before
                    # reading): that reply simply becomes due, as on a real line.
                    index, byte = self._next(index + 1, "TX"), 0
            self._tx = (index, byte)
            self._cond.notify_all()  # replies that just became due
        return len(data)

    def reset_input_buffer(self) -> None:
        # Accepted and ignored: spy records only the bytes read, so nothing in the capture is
        # flushed data; the replay delivers exactly what the driver read live.
        self._check_open()

    def reset_output_buffer(self) -> None:
        self._check_open()  # writes are checked at once: nothing waits to go out

    @property
    def out_waiting(self) -> int:
        self._check_open()
        return 0


def install_replay_handler() -> None:
    """Let :func:`serial.serial_for_url` find ``ndireplay://`` (idempotent; pyserial imports
    ``protocol_<scheme>`` from the packages in ``serial.protocol_handler_packages``)."""
    if "hexcal.mock_hw" not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append("hexcal.mock_hw")
