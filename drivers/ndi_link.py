"""The serial link to an NDI tracker, under :class:`~hexcal.drivers.ndi.NDITracker`: one
command and its reply (ASCII to its CR, or a binary ``BX`` frame by its length, bounded by a
deadline), what a timeout, a cut reply or a lost port becomes, and the tracker's reset by BREAK
or ``RESET:0`` (docs/ndi.md, "How the driver talks to the tracker")."""

from __future__ import annotations

import logging
import struct
import time
from typing import NamedTuple

import serial

from hexcal.drivers.base import SERIAL_IO_ERRORS
from hexcal.drivers.crc import crc16
from hexcal.drivers.ndi_codes import BX_START
from hexcal.drivers.ndi_protocol import (
    TrackerDisconnected,
    TrackerTimeout,
    _preview,
    build_command,
)

_IO_ERRORS = SERIAL_IO_ERRORS
#: What opening or reconfiguring the port raises for a bad name or a dead line.
_PORT_ERRORS: tuple[type[BaseException], ...] = (ValueError, *_IO_ERRORS)

log = logging.getLogger("hexcal.drivers.ndi")


class Exchange(NamedTuple):
    """One command and its reply, unchecked, with the host times (monotonic s) around it."""

    raw: bytes
    t_write: float  #: just before the command was handed to the port
    t_sent: float  #: when the port accepted it (write returned)
    t_recv: float  #: when the reply's last byte arrived


class SerialLink:
    """The wire half of :class:`~hexcal.drivers.ndi.NDITracker`: it reads and sets the
    tracker's attributes named here (the driver's constructor sets them)."""

    url: str
    port: serial.Serial | None
    baudrate: int
    timeout: float
    reset: str
    reset_timeout_s: float
    break_duration_s: float
    resync_s: float
    tracking: bool
    _dead: bool
    _resume_tracking: bool
    _resync: bool

    def _require_port(self) -> serial.Serial:
        if self.port is None:
            raise TrackerDisconnected(
                f"the tracker on {self.url} is not open: call open() first", self.url
            )
        if self._dead:
            raise TrackerDisconnected(
                f"the connection to the tracker on {self.url} was lost: plug it back in, then call reconnect()",
                self.url,
            )
        return self.port

    def _lost(self, exc: BaseException) -> TrackerDisconnected:
        self._dead = True
        # reconnect() must resume tracking: the loss, not the operator, ended it.
        self._resume_tracking = self._resume_tracking or self.tracking
        self.tracking = False
        return TrackerDisconnected(
            f"lost the connection to the tracker on {self.url} ({exc}): the cable or USB adapter was "
            "unplugged or the tracker was switched off. Plug it back in on the same port, then call "
            "reconnect()",
            self.url,
        )

    def _exchange(self, command: str, timeout: float, binary: bool = False) -> Exchange:
        """Send ``command``; return the raw reply, unchecked, and the host times around it."""
        port = self._require_port()
        data = build_command(command)
        try:
            if self._resync:
                self._drain(port, self.resync_s)
            # Anything unread is left over from a failed exchange (ndicapi does the same).
            port.reset_input_buffer()
            t_write = time.monotonic()  # the command cannot reach the tracker before this
            port.write(data)
            t_sent = time.monotonic()
            deadline = t_sent + timeout
            raw = (
                self._read_binary(port, command, deadline)
                if binary
                else self._read_line(port, command, deadline)
            )
            return Exchange(raw, t_write, t_sent, time.monotonic())
        except serial.SerialTimeoutException as exc:
            raise TrackerTimeout(
                f"could not send {command!r} to the tracker on {self.url} within {self.timeout:g} s "
                f"({exc}): check the cable and handshake settings",
                self.url,
            ) from exc
        except TrackerTimeout:
            self._resync = True
            raise
        except _IO_ERRORS as exc:
            raise self._lost(exc) from exc

    def _drain(self, port: serial.Serial, duration: float) -> None:
        """Read and discard for ``duration`` s (a late reply to a command that timed out)."""
        end = time.monotonic() + duration
        dropped = 0
        while time.monotonic() < end:
            dropped += len(port.read(max(1, port.in_waiting)))
        if dropped:
            log.info("tracker on %s: discarded %d late bytes", self.url, dropped)
        self._resync = False

    def _timeout(self, command: str, buf: bytes | bytearray, waited: float) -> TrackerTimeout:
        if not buf:
            msg = (
                f"no reply from the tracker on {self.url} to {command!r} within {waited:g} s: check "
                "that it is switched on and connected, and that nothing else uses the port"
            )
        else:
            msg = (
                f"incomplete reply from the tracker on {self.url} to {command!r}: {len(buf)} bytes "
                f"then nothing for {waited:g} s ({_preview(bytes(buf))}); the reply was cut off or bytes "
                "were lost, so it was discarded. If it persists check the cable and the baud rate"
            )
        return TrackerTimeout(msg, self.url, bytes(buf))

    def _read_line(
        self, port: serial.Serial, command: str, deadline: float, buf: bytearray | None = None
    ) -> bytes:
        buf = bytearray() if buf is None else buf
        start = time.monotonic()
        while True:
            chunk = port.read(max(1, port.in_waiting))
            if chunk:
                buf += chunk
                end = buf.find(b"\r")
                if end >= 0:
                    # The tracker speaks only when asked: bytes after the CR are noise, dropped
                    # by the next exchange's flush.
                    return bytes(buf[: end + 1])
            if time.monotonic() >= deadline:
                raise self._timeout(command, buf, round(deadline - start, 3))

    def _read_exact(
        self,
        port: serial.Serial,
        n: int,
        buf: bytearray,
        command: str,
        deadline: float,
        start: float,
    ) -> None:
        while len(buf) < n:
            chunk = port.read(min(n - len(buf), max(1, port.in_waiting)))
            buf += chunk
            if not chunk and time.monotonic() >= deadline:
                raise self._timeout(command, buf, round(deadline - start, 3))

    def _read_binary(self, port: serial.Serial, command: str, deadline: float) -> bytes:
        buf = bytearray()
        start = time.monotonic()
        self._read_exact(port, 2, buf, command, deadline, start)
        if bytes(buf[:2]) != BX_START:  # an ASCII reply (ERRORxx) or noise: read it to its CR
            if b"\r" in buf:
                return bytes(buf[: buf.find(b"\r") + 1])
            return self._read_line(port, command, deadline, buf)
        self._read_exact(port, 6, buf, command, deadline, start)
        (length,) = struct.unpack_from("<H", buf, 2)
        # A garbled length must not make us wait for 64 kB: the header CRC decides first.
        if crc16(buf[:4]) != struct.unpack_from("<H", buf, 4)[0]:
            return bytes(buf)  # parse_bx_reply reports the header CRC error
        self._read_exact(port, 6 + length + 2, buf, command, deadline, start)
        return bytes(buf)

    def _set_baud(self, baud: int) -> None:
        port = self._require_port()
        try:
            if port.baudrate != baud:
                port.baudrate = baud
        except _PORT_ERRORS as exc:
            raise self._lost(exc) from exc

    def _reset_tracker(self) -> None:
        """Reset the tracker to 9600 baud, by BREAK and/or the RESET command (see ``reset``)."""
        tried = []
        if self.reset in ("break", "auto"):
            tried.append("a serial BREAK at 9600 baud")
            if self._try_reset(None):
                return
        if self.reset in ("command", "auto"):
            # At 9600 (fresh tracker), at the working rate (left there by a session that could
            # not close), then at 9600 again: whether a tracker reset at another rate answers at
            # that rate or at 9600 is not documented, so both are covered.
            bauds = (9600,) if self.baudrate == 9600 else (9600, self.baudrate, 9600)
            for baud in bauds:
                tried.append(f"RESET:0 at {baud} baud")
                if self._try_reset(baud):
                    self._set_baud(9600)
                    return
        self._set_baud(9600)
        raise TrackerTimeout(
            f"the tracker on {self.url} did not answer RESETBE6F to {' nor '.join(tried)} "
            f"(waited {self.reset_timeout_s:g} s each): check that it is switched on, that this is "
            "its port and that the cable is a straight-through serial cable"
            + (
                "; a pty or network bridge cannot carry a BREAK, use reset='command' or 'auto'"
                if self.reset == "break"
                else ""
            ),
            self.url,
        )

    def _try_reset(self, baud: int | None) -> bool:
        """One reset attempt: a BREAK (baud None) or RESET:0 sent at ``baud``."""
        port = self._require_port()
        command = "RESET:0" if baud is not None else "BREAK"
        try:
            self._set_baud(9600 if baud is None else baud)
            port.reset_input_buffer()
            if baud is None:
                port.send_break(self.break_duration_s)
            else:
                port.write(build_command(command))
            reply = self._read_line(port, command, time.monotonic() + self.reset_timeout_s)
        except TrackerTimeout as exc:
            log.info("tracker on %s: no answer to %s (%s)", self.url, command, exc)
            return False
        except _IO_ERRORS as exc:
            raise self._lost(exc) from exc
        if reply.endswith(b"RESETBE6F\r"):
            return True
        log.info("tracker on %s: unexpected answer to %s: %s", self.url, command, _preview(reply))
        return False
