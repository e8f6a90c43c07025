"""A mock NDI Combined API tracker: the protocol state machine behind two real transports.

The device answers the subset of the API that :mod:`hexcal.drivers.ndi` uses, byte for byte as
documented in docs/ndi.md: BREAK or ``RESET`` -> ``RESETBE6F`` at 9600 baud; ``COMM`` (every baud code,
``A`` for 230400 included), ``INIT``, ``VER``, ``PHSR``, ``PHF``, ``PINIT``, ``PENA``, ``PDIS``,
``TSTART``, ``TSTOP``, ``TX`` (text) and ``BX`` (binary) with reply option 0001 or 0801.
Commands in the ``NAME:params`` form must carry a correct CRC (else ``ERROR04``); the ``NAME
params`` form carries none. Commands out of order get the error a tracker gives (``ERROR10``
before INIT, ``ERROR0C`` for TX outside tracking...); a reply option it does not simulate gets
``ERROR23`` (parameter out of range), as does 0x0800 when :attr:`MockNDITracker.all_transforms`
is False (an older tracker without it).

Its main tool (port handle 01) is the platform of a :class:`~hexcal.mock_hw.robot.MockRobot`;
``static_tools`` adds wired tools at fixed poses (handle -> position, quaternion), such as a
reference body on the base. Every reply form of TX/BX can be produced:

- a pose, or MISSING (port status and frame number) when the robot's ``tool_visible`` is False;
- out of volume: with reply option 0x0800 the pose with port status bit 0x40; without it the tool
  is reported MISSING with that bit (a tracker does not normally report a transform outside its
  characterised volume); 0x80 (partially out) comes with the pose either way;
- DISABLED for a handle initialised but not enabled (``PDIS`` disables one while tracking) and
  UNOCCUPIED for a tool pulled out of its port while tracking (:meth:`MockNDITracker.unplug_tool`),
  followed by port status and frame number (as sawNDITracker reads them) or bare (as ndicapi
  does: :attr:`MockNDITracker.records_with_status` False). BX has no UNOCCUPIED status byte
  (ndicapi, NDI's ndtrack sample): there the mock reports such a handle DISABLED;
- port status fault bits 8-15 on a handle (:attr:`MockNDITracker.port_status_extra`) and any
  system status word (:attr:`MockNDITracker.system_status`).

Timing, as on a real tracker: frame n (the counter starts at 1 when the device is created) is
measured at its frame boundary ``t0 + (n - 1) / frame_rate_hz`` on the device's ``clock``: the
robot's pose *as of that instant* (:meth:`MockRobot.tracker_sample` with ``at``), whenever the
first poll of the frame comes; later polls within the frame get the same reading. A command
takes effect when its last byte has crossed the serial line (10 bits per byte at the tracker's
current baud rate, counted from the host's write), so a TX/BX reply carries the newest frame at
that instant; the host's write returns at once, as a real port's does (the work is done when the
host next looks at the line, as of that instant). The reply itself is not slowed by its length:
``delay_s`` and ``jitter_s`` model the return path. :attr:`MockNDITracker.frame_times` records the true measurement instant of every
frame served, for tests and benchmarks of host-side time stamping. The tool is MISSING when the
robot's ``tool_visible`` is False; it is flagged out of volume (port status 0x40, or 0x80 within
``volume_margin_mm`` of the boundary) when outside ``volume_mm`` (see above for what reply option
0x0800 changes). With ``tool_plugged`` False (from the next reset on) the port is empty and
setup finds no tool.

Transports (one at a time per device):

- the pyserial URL handler :mod:`hexcal.mock_hw.protocol_ndimock`: ``ndimock://<name>?<options>``
  reaches the device registered under ``name`` (:func:`register_robot`,
  :func:`register_device`); with no name, a default device around ``MockRobot(left_hand())``
  (one per ``seed``). Importing this module registers the handler with pyserial;
- a pseudo-terminal, :class:`hexcal.mock_hw.pty_tracker.PtyTracker`.

URL options (all optional): ``seed`` (int, default device only), ``frame_rate`` (Hz), the fault
rates ``drop``, ``garble``, ``crc``, ``truncate``, ``nan`` (probability per tracking reply) and
``delay_ms``, ``jitter_ms``. They update the device's :class:`FaultSettings` when the URL opens.

Faults (on TX/BX replies; :meth:`MockNDITracker.inject` queues one-shot faults for the next
ones, the rates draw them at random): ``drop`` (no reply: the host times out), ``garble`` (a few
payload bytes replaced: CRC error), ``crc`` (payload intact, CRC field wrong), ``truncate`` (only
the first half of the reply, no CR). The number faults of :data:`NONFINITE_FAULTS` spoil a
*frame*, not a reply: the next frame measured (every poll of it, as a tracker serves one
measurement per frame) carries a non-finite number in its pose record, in replies that stay well
formed with valid CRCs — a firmware glitch no link check can catch: ``nan`` (position x is
NaN), ``inf`` (position z is +inf), ``nan_quaternion`` (qx is NaN), ``inf_rms`` (the RMS error
is +inf); the ``nan`` rate draws per frame. BX carries them as float32; TX's fixed-width digit
fields cannot, so there the field is spelled as C's printf would (``+   nan``), which no longer
follows the format. ``delay_s`` + uniform(0, ``jitter_s``) delays every reply.
The link itself: a wrong host baud rate makes the device drop what it receives (framing errors),
and :meth:`MockNDITracker.unplug` / :meth:`replug` pull and reinsert the URL transport's cable.

The reply formats and the fault kinds are in :mod:`hexcal.mock_hw.ndi_replies` (importable from
here too); this module holds the device's state machine, its timing and the ``ndimock://``
registry.
"""

from __future__ import annotations

import math
import re
import struct
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import fields

import numpy as np

from hexcal.drivers.crc import crc16_hex
from hexcal.mock_hw.ndi_replies import (
    FAULT_KINDS,
    LINK_FAULTS,
    NONFINITE_FAULTS,
    FaultSettings,
    Sample,
    ToolState,
    _spoiled,
    format_bx_reply,
    format_tx_reply,
    with_crc,
)
from hexcal.mock_hw.robot import MockRobot

URL_SCHEME = "ndimock"

#: COMM's baud digit -> baud rate.
COMM_BAUD = {
    "0": 9600,
    "1": 14400,
    "2": 19200,
    "3": 38400,
    "4": 57600,
    "5": 115200,
    "6": 921600,
    "7": 1228739,
    "A": 230400,  # ndicapi.h NDI_230400 = 10, sent as "A" (ndicapi.cxx ndiCOMMHelper)
}

OCCUPIED, INITIALIZED, ENABLED = 0x01, 0x10, 0x20

#: Bits on the line per byte: start, 8 data, stop (8N1).
BITS_PER_BYTE = 10
OUT_OF_VOLUME, PARTIALLY_OUT = 0x40, 0x80

#: The characterised volume, tracker frame, mm: (min corner, max corner).
DEFAULT_VOLUME_MM = ((-1500.0, -1500.0, -1500.0), (1500.0, 1500.0, 3000.0))


# ------------------------------------------------------------------------------------------------
# The device
# ------------------------------------------------------------------------------------------------
_COMMAND = re.compile(rb"([A-Z0-9]+)([: ]?)(.*)", re.S)


class MockNDITracker:
    """The simulated tracker. ``robot`` (default: ``MockRobot(left_hand(), seed=seed)``) gives
    the tool's pose; ``seed`` also drives the fault draws; ``clock`` (s) times the frames;
    ``log_len`` bounds :attr:`frame_times`."""

    #: How many frames :attr:`frame_times` remembers by default (about 17 s at 60 Hz: bounded
    #: so that a long run's memory stays flat; benchmarks that need more pass ``log_len``).
    FRAME_LOG_LEN = 1_000

    def __init__(
        self,
        robot: MockRobot | None = None,
        *,
        seed: int = 0,
        frame_rate_hz: float = 60.0,
        volume_mm: tuple[Sequence[float], Sequence[float]] = DEFAULT_VOLUME_MM,
        volume_margin_mm: float = 50.0,
        faults: FaultSettings | None = None,
        clock: Callable[[], float] = time.monotonic,
        name: str = "ndimock",
        log_len: int | None = None,
        static_tools: Mapping[int, tuple[Sequence[float], Sequence[float]]] | None = None,
    ):
        if robot is None:
            from hexcal.sim.robots import left_hand

            robot = MockRobot(left_hand(), seed=seed)
        self.robot = robot
        self.name = name
        self.frame_rate_hz = float(frame_rate_hz)
        self.volume_mm = (np.asarray(volume_mm[0], float), np.asarray(volume_mm[1], float))
        self.volume_margin_mm = float(volume_margin_mm)
        self.faults = faults if faults is not None else FaultSettings()
        self.clock = clock
        self._rng = np.random.default_rng([seed, 0x4E4449])
        self._cond = threading.Condition()  # guards everything below; signals new output
        self._pending: deque[tuple[float, bytes]] = deque()  # (release time, bytes) in flight
        self._ready = bytearray()  # arrived at the host, not read yet
        self._inbuf = bytearray()
        self._once: deque[str] = deque()  # link faults for the next replies
        self._spoil_frames: deque[str] = deque()  # number faults for the next frames
        self._t0 = clock()
        #: Every command line received (text), most recent last.
        self.commands: deque[str] = deque(maxlen=500)
        #: The sample sent for each handle in the last TX/BX reply (before wire rounding).
        self.last_sent: dict[int, Sample | None] = {}
        #: How many times input arrived at the wrong baud rate (dropped, as by a real UART).
        self.framing_errors = 0
        #: The wired tool is in its port (port handle 01). Takes effect at the next reset.
        self.tool_plugged = True
        #: The system status word sent with every TX/BX reply (e.g. 0x0200 temperature).
        self.system_status = 0
        #: Port status bits ORed into a handle's port status in every TX/BX reply (handle ->
        #: bits, e.g. {0x01: 0x1000} for a processing exception on the main tool).
        self.port_status_extra: dict[int, int] = {}
        #: The tracker accepts reply option 0x0800 (False: an older one, ERROR23 to it).
        self.all_transforms = True
        #: DISABLED / UNOCCUPIED records carry port status and frame number (False: bare).
        self.records_with_status = True
        # Wired tools at fixed poses: handle -> (position mm, quaternion, rms mm).
        self._static: dict[int, Sample] = {}
        for handle, (position, quaternion) in (static_tools or {}).items():
            if not 0x02 <= handle <= 0xFF:
                raise ValueError(
                    f"static tool handle {handle:#x}: use 0x02 to 0xFF (01 is the robot)"
                )
            q = np.asarray(quaternion, float)
            self._static[handle] = (np.asarray(position, float), q / np.linalg.norm(q), 0.02)
        self._unplugged: set[int] = set()  # handles whose tool was pulled out
        self.plugged = True
        self.generation = 0  # bumped at each unplug: ports opened before are dead
        #: (frame number, ``clock()`` time s at which it was measured) of every frame served in a
        #: TX/BX reply, oldest first; the ground truth for the host's frame time stamps.
        self.frame_times: deque[tuple[int, float]] = deque(maxlen=log_len or self.FRAME_LOG_LEN)
        # Commands received and not acted on yet: (line, device clock s, time.monotonic() s
        # at which each takes effect), and the times of the one being handled.
        self._inbox: deque[tuple[bytes, float, float]] = deque()
        self._t_cmd: tuple[float, float] | None = None
        self._power_on()

    # -- state ----------------------------------------------------------------------------------
    def _power_on(self) -> None:
        self.baud = 9600
        self.initialized = False
        self.tracking = False
        wired = ([0x01] if self.tool_plugged else []) + sorted(self._static)
        self.ports: dict[int, int] = {h: OCCUPIED for h in wired if h not in self._unplugged}
        self._cached: tuple[int, Sample | None] | None = None

    def unplug_tool(self, handle: int = 0x01) -> None:
        """Pull the tool out of its port: while tracking, TX reports the handle UNOCCUPIED
        (BX: disabled) until it is freed (PHF) or the tracker reset; setup then finds no tool
        there until :meth:`plug_tool`."""
        with self._cond:
            self._process_locked()
            self._unplugged.add(handle)
            if handle in self.ports:
                self.ports[handle] &= ~OCCUPIED

    def plug_tool(self, handle: int = 0x01) -> None:
        """Plug the tool back in: its handle is occupied again and must be set up again (PINIT,
        PENA), as a freshly plugged tool must."""
        with self._cond:
            self._process_locked()
            self._unplugged.discard(handle)
            if handle == 0x01 or handle in self._static:
                self.ports[handle] = OCCUPIED

    def frame_number(self, at: float | None = None) -> int:
        """The tracker's frame counter at ``clock()`` time ``at`` (s; None: now): frames since the
        device was created, at ``frame_rate_hz``."""
        t = self.clock() if at is None else at
        return 1 + math.floor((t - self._t0) * self.frame_rate_hz)

    def frame_time(self, frame: int) -> float:
        """The ``clock()`` time (s) at which frame ``frame`` is measured: its frame boundary."""
        return self._t0 + (frame - 1) / self.frame_rate_hz

    def inject(self, fault: str, count: int = 1) -> None:
        """Apply ``fault`` (one of :data:`FAULT_KINDS`) to the next ``count`` tracking replies
        (a link fault) or frames measured (a number fault, :data:`NONFINITE_FAULTS`)."""
        if fault not in FAULT_KINDS:
            raise ValueError(f"unknown fault {fault!r}; choose from {', '.join(FAULT_KINDS)}")
        with self._cond:
            queue = self._spoil_frames if fault in NONFINITE_FAULTS else self._once
            queue.extend([fault] * count)

    def configure(self, **settings: float) -> None:
        """Update :attr:`faults` (drop, garble, crc, truncate, nan, delay_s, jitter_s)."""
        known = {f.name for f in fields(FaultSettings)}
        for key, value in settings.items():
            if key not in known:
                raise ValueError(
                    f"unknown fault setting {key!r}; choose from {', '.join(sorted(known))}"
                )
            setattr(self.faults, key, float(value))

    # -- the cable (URL transport) ----------------------------------------------------------------
    def unplug(self) -> None:
        """Pull the cable: ports opened through the URL handler fail from now on, and nothing in
        flight arrives. The tracker itself keeps its state (baud rate, tracking), as a real one
        does when only the cable goes."""
        with self._cond:
            self._process_locked()  # what reached the tracker before the pull is acted on
            self.plugged = False
            self.generation += 1
            self._discard_locked()
            self._cond.notify_all()

    def replug(self) -> None:
        """Plug the cable back in: the URL can be opened again."""
        with self._cond:
            self.plugged = True
            self._cond.notify_all()

    # -- host side of the wire ----------------------------------------------------------------------
    def on_break(self) -> None:
        """A serial BREAK: reset to 9600 baud and answer RESETBE6F."""
        with self._cond:
            self._process_locked()
            self._discard_locked()
            self._inbuf.clear()
            self.commands.append("<BREAK>")
            self._power_on()
            self._emit(with_crc(b"RESET"))

    def feed(self, data: bytes, host_baud: int | None = None) -> None:
        """Bytes from the host, sent at ``host_baud`` (None: unknown, assumed right).

        Each complete command is acted on *as of* the instant its last byte has crossed the
        line; the work is done when the host next looks at the line (reads, polls, flushes), so
        that the host's write returns at once, as a real port's does."""
        with self._cond:
            self._process_locked()  # earlier commands first: COMM changes the rate heard
            if host_baud is not None and host_baud != self.baud:
                self.framing_errors += 1
                self._inbuf.clear()
                return
            t_clock, t_mono = self.clock(), time.monotonic()
            earlier = len(self._inbuf)  # bytes of a command begun by an earlier write
            self._inbuf += data
            done = 0
            while (end := self._inbuf.find(b"\r")) >= 0:
                line = bytes(self._inbuf[:end])
                del self._inbuf[: end + 1]
                # The command takes effect when its CR has crossed the line: the bytes of this
                # write up to it, at the current baud rate (a command sets the next one's rate).
                done += end + 1
                wire_s = max(done - earlier, 1) * BITS_PER_BYTE / self.baud
                self._inbox.append((line, t_clock + wire_s, t_mono + wire_s))
            if len(self._inbuf) > 4096:  # no CR for that long: line noise, as a UART overruns
                self._inbuf.clear()
            if self._inbox:
                self._cond.notify_all()

    def _process_locked(self) -> None:
        """Act on the commands received so far, each as of the instant it arrived."""
        while self._inbox:
            line, t_clock, t_mono = self._inbox.popleft()
            self._t_cmd = (t_clock, t_mono)
            try:
                self._handle(line)
            finally:
                self._t_cmd = None

    def read(self, size: int, timeout: float | None, generation: int | None = None) -> bytes | None:
        """Up to ``size`` bytes that have arrived, waiting up to ``timeout`` s (None: forever)
        for the first; None when the cable was pulled (``generation`` no longer current)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while True:
                if generation is not None and (not self.plugged or generation != self.generation):
                    return None
                now = time.monotonic()
                self._release_locked(now)
                if self._ready:
                    out = bytes(self._ready[:size])
                    del self._ready[:size]
                    return out
                if deadline is not None and now >= deadline:
                    return b""
                wait = None if deadline is None else deadline - now
                if self._pending:
                    until_next = max(self._pending[0][0] - now, 0.0)
                    wait = until_next if wait is None else min(wait, until_next)
                self._cond.wait(wait)

    def in_waiting(self) -> int:
        """Bytes that have arrived at the host and are not read yet."""
        with self._cond:
            self._release_locked(time.monotonic())
            return len(self._ready)

    def pop_arrived(self) -> bytes:
        """Everything that has arrived (for a transport that forwards bytes, like the pty)."""
        with self._cond:
            self._release_locked(time.monotonic())
            out = bytes(self._ready)
            self._ready.clear()
            return out

    def next_arrival_in(self) -> float | None:
        """Seconds until the next byte in flight arrives (None: nothing in flight)."""
        with self._cond:
            self._process_locked()
            if self._ready:
                return 0.0
            return max(self._pending[0][0] - time.monotonic(), 0.0) if self._pending else None

    def discard_input(self) -> None:
        """The host flushed its receive buffer: what has arrived is gone; what is still in flight
        (a delayed reply) still comes, as on a real line."""
        with self._cond:
            self._release_locked(time.monotonic())
            self._ready.clear()

    def discard_all(self) -> None:
        """The line went dead: nothing that has arrived or is in flight will be read."""
        with self._cond:
            self._process_locked()
            self._discard_locked()

    def _discard_locked(self) -> None:
        self._pending.clear()
        self._ready.clear()

    def _release_locked(self, now: float) -> None:
        self._process_locked()
        while self._pending and self._pending[0][0] <= now:
            self._ready += self._pending.popleft()[1]

    # -- replies and faults ---------------------------------------------------------------------------
    def _draw_fault(self) -> str | None:
        """The fault of the next tracking reply: a queued one-shot, else one drawn by the rates."""
        if self._once:
            return self._once.popleft()
        for kind in LINK_FAULTS:
            rate = getattr(self.faults, kind)
            if rate > 0.0 and self._rng.random() < rate:
                return kind
        return None

    def _emit(self, data: bytes, fault: str | None = None) -> None:
        if fault == "drop":
            return
        if fault == "garble":
            data = self._garble(data)
        elif fault == "crc":
            data = self._bad_crc(data)
        elif fault == "truncate":
            data = data[: len(data) // 2]
        delay = self.faults.delay_s
        if self.faults.jitter_s > 0.0:
            delay += float(self._rng.uniform(0.0, self.faults.jitter_s))
        # Not before the command that asked for it has arrived (BREAK: at once).
        release = (self._t_cmd[1] if self._t_cmd is not None else time.monotonic()) + delay
        if self._pending:  # a serial line keeps the order of what it carries
            release = max(release, self._pending[-1][0])
        self._pending.append((release, data))
        self._cond.notify_all()

    def _garble(self, data: bytes) -> bytes:
        out = bytearray(data)
        binary = data[:2] == b"\xc4\xa5"
        lo, hi = (6, len(data) - 2) if binary else (0, len(data) - 5)  # payload only
        n = min(int(self._rng.integers(1, 4)), hi - lo)
        for i in self._rng.choice(np.arange(lo, hi), size=n, replace=False):
            old = out[i]
            while True:
                new = (
                    int(self._rng.integers(0, 256))
                    if binary
                    else int(self._rng.integers(0x21, 0x7F))
                )
                if new != old:
                    break
            out[i] = new
        return bytes(out)

    @staticmethod
    def _bad_crc(data: bytes) -> bytes:
        if data[:2] == b"\xc4\xa5":
            (crc,) = struct.unpack_from("<H", data, len(data) - 2)
            return data[:-2] + struct.pack("<H", crc ^ 0x5A5A)
        crc = int(data[-5:-1], 16)
        return data[:-5] + b"%04X" % (crc ^ 0x5A5A) + b"\r"

    def _reply(self, payload: bytes | str) -> None:
        if isinstance(payload, str):
            payload = payload.encode("ascii")
        self._emit(with_crc(payload))

    def _error(self, code: int) -> None:
        self._reply(f"ERROR{code:02X}")

    # -- the command interpreter ----------------------------------------------------------------------
    def _handle(self, line: bytes) -> None:
        self.commands.append(line.decode("ascii", "replace"))
        m = _COMMAND.fullmatch(line)
        if m is None:
            return self._error(0x01)
        name, sep, rest = m.groups()
        if sep == b":":
            if len(rest) < 4 or crc16_hex(line[:-4]) != line[-4:]:
                return self._error(0x04)
            rest = rest[:-4]
        handler = getattr(self, "_cmd_" + name.decode(), None)
        if handler is None:
            return self._error(0x01)
        if not self.initialized and name not in (b"RESET", b"COMM", b"INIT", b"VER", b"BEEP"):
            return self._error(0x10)
        return handler(rest.decode("ascii", "replace").strip())

    def _cmd_RESET(self, params: str) -> None:
        self._power_on()
        self._reply(b"RESET")

    def _cmd_COMM(self, params: str) -> None:
        if len(params) != 5 or params[0] not in COMM_BAUD or params[1:] != "0000":
            return self._error(0x06)
        self._reply(b"OKAY")  # at the old rate; the switch follows
        self.baud = COMM_BAUD[params[0]]

    def _cmd_INIT(self, params: str) -> None:
        self.initialized = True
        self._reply(b"OKAY")

    def _cmd_VER(self, params: str) -> None:
        self._reply(b"hexcal mock NDI tracker\nCombined API subset: TX, BX 0001 and 0801")

    def _cmd_BEEP(self, params: str) -> None:
        self._reply(b"1")

    def _handle_param(self, params: str) -> int | None:
        try:
            handle = int(params[:2], 16)
        except ValueError:
            return None
        return handle if len(params) >= 2 and handle in self.ports else None

    def _cmd_PHSR(self, params: str) -> None:
        try:
            option = int(params or "00", 16)
        except ValueError:
            return self._error(0x07)
        if option > 4:
            return self._error(0x23)
        chosen = []
        for handle, status in sorted(self.ports.items()):
            init, enabled = bool(status & INITIALIZED), bool(status & ENABLED)
            occupied = bool(status & OCCUPIED)
            if (
                option == 0
                or (option == 1 and not occupied)  # to be freed: the tool was pulled out
                or (option == 2 and occupied and not init)
                or (option == 3 and occupied and init and not enabled)
                or (option == 4 and occupied and enabled)
            ):
                chosen.append(f"{handle:02X}{status:03X}")
        self._reply(f"{len(chosen):02X}" + "".join(chosen))

    def _cmd_PHF(self, params: str) -> None:
        handle = self._handle_param(params)
        if handle is None:
            return self._error(0x08)
        if not self.ports[handle] & OCCUPIED:  # an emptied port's handle is gone once freed
            del self.ports[handle]
        self._reply(b"OKAY")

    def _cmd_PINIT(self, params: str) -> None:
        handle = self._handle_param(params)
        if handle is None:
            return self._error(0x08)
        self.ports[handle] |= INITIALIZED
        self._reply(b"OKAY")

    def _cmd_PDIS(self, params: str) -> None:
        handle = self._handle_param(params)
        if handle is None:
            return self._error(0x08)
        self.ports[handle] &= ~ENABLED
        self._reply(b"OKAY")

    def _cmd_PENA(self, params: str) -> None:
        handle = self._handle_param(params)
        if handle is None:
            return self._error(0x08)
        if params[2:] not in ("S", "D", "B"):
            return self._error(0x09)
        if not self.ports[handle] & INITIALIZED:
            return self._error(0x0E)
        self.ports[handle] |= ENABLED
        self._reply(b"OKAY")

    def _cmd_TSTART(self, params: str) -> None:
        if self.tracking:
            return self._error(0x0C)
        self.tracking = True
        self._reply(b"OKAY")

    def _cmd_TSTOP(self, params: str) -> None:
        if not self.tracking:
            return self._error(0x0C)
        self.tracking = False
        self._reply(b"OKAY")

    def _tool_states(self, mode: int = 0x0001) -> list[ToolState]:
        """Every initialised handle's record for a TX/BX reply with reply option ``mode``."""
        now = self.clock()
        frame = self.frame_number(self._t_cmd[0] if self._t_cmd is not None else now)
        if self._cached is None or self._cached[0] != frame:  # one measurement per frame
            measured = self.frame_time(frame)
            self.frame_times.append((frame, measured))
            measurement = self.robot.tracker_sample(at=self._robot_time(measured, now))
            self._cached = (frame, self._spoil(measurement))
        states = []
        for handle, status in sorted(self.ports.items()):
            if not status & INITIALIZED:
                continue
            status |= self.port_status_extra.get(handle, 0)
            if not status & OCCUPIED or not status & ENABLED:
                states.append(
                    ToolState(
                        handle,
                        None,
                        status,
                        frame,
                        disabled=bool(status & OCCUPIED),
                        unoccupied=not status & OCCUPIED,
                        with_status=self.records_with_status,
                    )
                )
                continue
            sample = self._cached[1] if handle == 0x01 else self._static.get(handle)
            # A spoiled (non-finite) position is a glitch of the numbers, sent as it is.
            if sample is not None and np.all(np.isfinite(sample[0])):
                status |= self._volume_bits(sample[0])
                if status & OUT_OF_VOLUME and not mode & 0x0800:
                    sample = None  # not normally reported: MISSING, with the bit saying why
            states.append(ToolState(handle, sample, status, frame))
            self.last_sent[handle] = sample
        return states

    def _robot_time(self, t: float, now: float) -> float:
        """Device clock time ``t`` on the robot's clock (the two clocks may differ in tests: a
        fake device clock, say; what is kept is how long ago ``t`` was)."""
        if self.robot.clock is self.clock:
            return t
        return self.robot.clock() - (now - t)

    def _volume_bits(self, position: np.ndarray) -> int:
        lo, hi = self.volume_mm
        inside = float(np.min(np.minimum(position - lo, hi - position)))  # distance to a face
        if inside < 0.0:
            return OUT_OF_VOLUME
        return PARTIALLY_OUT if inside < self.volume_margin_mm else 0

    def _tracking_mode(self, params: str) -> int | None:
        """The reply option of a TX/BX command, or None once the error reply is sent."""
        if not self.tracking:
            self._error(0x0C)
            return None
        try:
            mode = int(params or "0001", 16)
        except ValueError:
            self._error(0x07)
            return None
        if not mode & 0x0001:  # only transforms and status are simulated
            self._error(0x09)
            return None
        if mode & ~(0x0801 if self.all_transforms else 0x0001):
            self._error(0x23)
            return None
        return mode

    def _cmd_TX(self, params: str) -> None:
        mode = self._tracking_mode(params)
        if mode is not None:
            reply = format_tx_reply(self._tool_states(mode), self.system_status)
            self._emit(reply, self._draw_fault())

    def _cmd_BX(self, params: str) -> None:
        mode = self._tracking_mode(params)
        if mode is not None:
            reply = format_bx_reply(self._tool_states(mode), self.system_status)
            self._emit(reply, self._draw_fault())

    def _spoil(self, sample: Sample | None) -> Sample | None:
        """A new frame's measurement, with a number fault if one is due (queued or drawn)."""
        if self._spoil_frames:
            kind = self._spoil_frames.popleft()
        elif self.faults.nan > 0.0 and self._rng.random() < self.faults.nan:
            kind = "nan"
        else:
            return sample
        return None if sample is None else _spoiled(sample, *NONFINITE_FAULTS[kind])
