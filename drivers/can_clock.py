"""The CAN interface's clock against the host's, for :class:`~hexcal.drivers.can_encoders.LegEncoders`.

Every frame carries the time the bus interface stamped it (``msg.timestamp``); the driver places
positions on SYNCs by those bus times, and its own SYNCs (stamped with ``time.monotonic()``) go on
the bus clock by the offset between the two clocks: the smallest arrival − bus time seen over the
last few seconds (:class:`BusClock`).

Clock jumps. The bus interface's clock is not the host's and can jump: an adapter that resets
restarts its clock, SocketCAN stamps with the system time, which an operator or NTP may step,
and one corrupt timestamp is enough to matter. A frame whose (arrival − bus time) differs from
the learnt offset by more than ``clock_jump_s`` (1 s by default: a thousand times the jitter of
a stamp, more than any stall a working receive thread has) cannot be placed on the bus clock,
so its bus time is not trusted: it takes no part in attribution, closing or the offset, and a
position it carries is discarded and its set flagged (naming the leg and the jump). When the
next frame is on the known clock again, those were stray stamps: the driver says so (a warning
naming the bus and the offset the first time, at info level after). If instead frames keep
coming with one new offset (at least three, over more than two SYNC periods) the clock itself
has jumped: the driver re-anchors — the new offset replaces the old one and the open sets are
moved onto the new clock — logs a warning naming the bus and the jump, once, and flags the set
it happens in. A single frame stamped an hour off thus costs one flagged set, a clock reset a
few; neither leaves the driver stuck until a restart. (``status()`` counts both.)
"""

from __future__ import annotations

import logging
import math
import time

# The driver's logger: these messages were always logged as hexcal.drivers.can_encoders's, and
# operators and tests select them by that name.
log = logging.getLogger("hexcal.drivers.can_encoders")


class _JumpCandidate:
    """Frames stamped off the bus clock by about one amount, since ``first_t`` (monotonic s):
    a clock jump once enough of them agree (see :meth:`BusClock._step`)."""

    __slots__ = ("first_t", "frames", "lag", "lag_min", "offset")

    def __init__(self, first_t: float, lag: float, offset: float):
        self.first_t = first_t
        self.lag = lag  # the first frame's arrival − bus time, s
        self.lag_min = lag  # the smallest of them, s: the new offset if it is a jump
        self.offset = offset  # the offset (s) they stray from
        self.frames = 0


class BusClock:
    """The bus interface's clock on ``bus_name`` against the host's monotonic clock, for one run
    of the driver (a new run starts a new clock).

    ``jump_s``: how far (s) a frame's arrival − bus time may stray from the learnt offset before
    its stamp is not trusted; ``confirm_s``: how long (s) frames must show one new offset for it
    to be taken as a jump of the clock itself. ``jumps`` counts the jumps followed,
    ``untrusted`` the frames whose bus time was not trusted. Not thread-safe: the driver calls
    it under its lock.
    """

    def __init__(self, bus_name: str, jump_s: float, confirm_s: float):
        self.bus_name = bus_name
        self.jump_s = jump_s
        self.confirm_s = confirm_s
        # Bus clock → monotonic: the smallest (arrival − bus time) in this and the last window.
        self._offset_min = [math.inf, math.inf]
        self._offset_window_end = 0.0
        self._jump: _JumpCandidate | None = None  # frames off the clock, not yet explained
        self.jumps = 0
        self.untrusted = 0
        self._warned_stamp = False

    @property
    def offset(self) -> float:
        """Arrival − bus time (s): the smallest over this and the last window; inf before the
        first frame."""
        return min(self._offset_min)

    def place(self, stamp: float | None, t: float) -> tuple[float, bool, float | None]:
        """A frame stamped ``stamp`` by the interface arrived at monotonic ``t``: its bus time (s
        on the interface's clock), whether it is trusted, and the shift (s) to move bus times
        taken so far onto the clock when this frame confirmed a jump (None otherwise). Learns
        the clock offset and follows its jumps (module docstring)."""
        # No stamp (or no number): stamped on arrival, on the wall clock as python-can does.
        ts = stamp if stamp and math.isfinite(stamp) else time.time() - time.monotonic() + t
        if t >= self._offset_window_end:  # a fresh window every 5 s follows clock drift
            self._offset_min = [math.inf, self._offset_min[0]]
            self._offset_window_end = t + 5.0
        lag = t - ts
        offset = min(self._offset_min)
        if offset != math.inf and abs(lag - offset) > self.jump_s:
            shift = self._step(t, lag, offset)
            return ts, shift is not None, shift
        if self._jump is not None:  # on the known clock again: what strayed were frames' stamps
            self._stray_stamps(self._jump)
            self._jump = None
        if lag < self._offset_min[0]:
            self._offset_min[0] = lag
        return ts, True, None

    def peek(self, stamp: float | None, t: float) -> float | None:
        """A frame's bus time (s) if its stamp is on the learnt clock, else None; learns
        nothing (for the echoes of the driver's own frames)."""
        offset = min(self._offset_min)
        if not stamp or not math.isfinite(stamp) or offset == math.inf:
            return None
        return stamp if abs(t - stamp - offset) <= self.jump_s else None

    def to_bus(self, t: float) -> float:
        """Monotonic time ``t`` on the bus clock (the offset errs early: a frame is never
        placed before the SYNC it answers)."""
        offset = min(self._offset_min)
        if offset == math.inf:
            offset = time.monotonic() - time.time()
        return t - offset

    def _step(self, t: float, lag: float, offset: float) -> float | None:
        """A frame arrived ``lag`` s after its bus time, ``offset`` expected: count it towards a
        clock jump; the shift (s) when it confirms one (re-anchored: its stamp holds now)."""
        jump = self._jump
        if jump is None or abs(lag - jump.lag) > self.jump_s / 2:
            if jump is not None:
                self._stray_stamps(jump)
            jump = self._jump = _JumpCandidate(t, lag, offset)
        jump.lag_min = min(jump.lag_min, lag)
        jump.frames += 1
        if jump.frames >= 3 and t - jump.first_t >= self.confirm_s:
            return self._reanchor(jump.lag_min, offset)
        self.untrusted += 1
        return None

    def _stray_stamps(self, jump: _JumpCandidate) -> None:
        """Frames stamped off the clock turned out not to be a jump (the frames after them are
        on the known clock): say so — a warning the first time, then at info level."""
        level = logging.INFO if self._warned_stamp else logging.WARNING
        self._warned_stamp = True
        log.log(
            level,
            "%s: %d frame(s) stamped %+.3f s off the bus clock (against the host clock) — "
            "their bus times were not trusted, positions in them discarded and their sets "
            "flagged; the clock itself did not jump (a corrupt timestamp?)",
            self.bus_name,
            jump.frames,
            jump.offset - jump.lag,
        )

    def _reanchor(self, new: float, old: float) -> float:
        """The bus clock jumped: (arrival − bus time) is ``new`` s now, ``old`` s before. The
        offset follows; returns the shift (s) that moves a bus time on the old clock to the same
        instant on the new one."""
        self._offset_min = [new, new]
        self._jump = None
        self.jumps += 1
        return old - new
