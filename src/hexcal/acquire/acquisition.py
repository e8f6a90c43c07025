"""Acquisition: pair the tracker's poses with the six leg readings into recorded poses.

Both streams are stamped on one monotonic clock (``time.monotonic``) with the instant the
device measured: a leg-reading set with the SYNC that latched it, a tracker sample with its
frame's measurement time estimated from the tracker's frame numbers (see
docs/ndi.md, "Timing: the frame clock"). A pose is
recorded from a *still window*: every tracker sample and every leg-reading set whose arrival
time falls in ``[t_end − duration, t_end]``. A pose taken during a device fault is refused,
never kept: by default one flagged sample in the window (a tool MISSING for a frame, a CRC
error, a cut reply, a CAN set with a late or lost position, an error frame, a lost heartbeat, a
disconnected port) refuses the pose, with the fault that touched most samples named first — the
operator records again at the same pose once the fault is gone. A lab whose devices glitch now
and then may allow a share of flagged samples (``max_fault_share``): those are left out of the
average and named in the pose's ``notes``. The pose is also refused when the platform or a leg
moved during the window, or when a stream delivered too few good samples.

Numbers no pose can have are faults too. The drivers flag a NaN or an infinity a device sent
(``tracker frame 1234: non-finite position ...``); behind them, :func:`record_pose` checks every
sample again — a tracker sample whose position or quaternion is not finite (or not of shape
(3,) / (4,)) becomes a fault sample without a pose, a reading set with a non-finite reading is
flagged — and refuses a window whose averages come out non-finite. Comparisons with NaN are
false, so without this a NaN would pass every still-window check, and a session file cannot
hold it.

Motion is judged by *drift*: how far the mean of the window's second half lies from the mean of
its first half. Its noise is 2σ/√n, so the thresholds hold whatever the instruments' noise (a
max − min spread grows with the noise and with the number of samples, and refused still poses
of a tracker noisier than the thresholds assumed). The spreads are still measured and kept with
each pose. The raw samples behind each recorded pose, flagged ones
included, are kept for the session file.

The sources are small interfaces (:class:`PoseSource`, :class:`LegSource`); the serial tracker
and CAN encoder drivers implement them, and so do test doubles.
"""

from __future__ import annotations

import logging
import math
import re
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.errors import RefusedError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrackerSample:
    """One tracker reading: arrival time t (monotonic s), position (3,) mm, unit quaternion
    (4,) scalar first, RMS error mm; ``fault`` is None or a sentence (tool missing, CRC...);
    ``t_uncertainty_s``: half-width (s) of the interval the measurement instant is known to lie
    in (0: taken as exact)."""

    t: float
    position: np.ndarray | None
    quaternion: np.ndarray | None
    rms_mm: float = float("nan")
    fault: str | None = None
    t_uncertainty_s: float = 0.0


@dataclass(frozen=True)
class LegSample:
    """One set of six readings: arrival time t (monotonic s), readings (6,) mm (NaN when a leg
    is missing), the faults the bus reported for it, and ``reboots``: how many times each
    leg's encoder had rebooted since the source started (empty: the source does not tell)."""

    t: float
    readings: np.ndarray
    faults: tuple[str, ...] = ()
    reboots: tuple[int, ...] = ()

    @property
    def complete(self) -> bool:
        """Six finite readings and no fault."""
        r = _array(self.readings, 6)
        return not self.faults and r is not None and bool(np.all(np.isfinite(r)))


class PoseSource(Protocol):
    def sample(self) -> TrackerSample:
        """Block until the next tracker sample (stamped on arrival)."""


class LegSource(Protocol):
    def sample(self) -> LegSample:
        """Block until the next set of six readings (stamped on arrival)."""


@dataclass(frozen=True)
class StillWindow:
    """How long the platform must be still, and how still: the largest drift (second half's
    mean − first half's mean) of the tracker position per axis (mm), of its orientation (deg)
    and of each leg reading (mm)."""

    duration_s: float = 0.5
    max_position_drift_mm: float = 0.05
    max_angle_drift_deg: float = 0.01
    max_reading_drift_mm: float = 0.01
    min_tracker_samples: int = 5
    min_leg_samples: int = 5
    #: Largest share of a stream's samples in the window that may be flagged and left out of
    #: the average; 0 (the default): any flagged sample refuses the pose.
    max_fault_share: float = 0.0
    #: When both are set, a window holds exactly this many tracker samples and leg reading
    #: sets: the first measured from its start, however long they take (a host too busy to
    #: read a frame waits for the next one), up to ``3 × duration_s``. None (the default):
    #: every sample measured within ``duration_s``.
    tracker_samples: int | None = None
    leg_samples: int | None = None

    @property
    def counted(self) -> bool:
        """Whether a window is so many samples (else so many seconds)."""
        return self.tracker_samples is not None and self.leg_samples is not None


@dataclass
class RecordedPose:
    """A pose: the window's mean tracker pose and mean readings, with the raw samples."""

    t: float  #: monotonic time at the window's end, s
    position: np.ndarray  #: (3,) mm
    quaternion: np.ndarray  #: (4,) scalar first
    readings: np.ndarray  #: (6,) mm
    tracker_samples: list[TrackerSample] = field(repr=False)
    leg_samples: list[LegSample] = field(repr=False)
    position_spread_mm: float = 0.0
    angle_spread_deg: float = 0.0
    reading_spread_mm: float = 0.0
    alignment_s: float = 0.0  #: difference between the two streams' mean sample times
    notes: tuple[str, ...] = ()  #: flagged samples left out of the average, and why
    #: The structure's temperature at the pose, degC, when a thermometer or the operator gave it.
    temperature: float | None = None

    @property
    def good_tracker_samples(self) -> list[TrackerSample]:
        """The tracker samples averaged into the pose (the flagged ones left out)."""
        return [s for s in self.tracker_samples if not s.fault and s.position is not None]

    @property
    def good_leg_samples(self) -> list[LegSample]:
        """The leg reading sets averaged into the pose (the flagged ones left out)."""
        return [s for s in self.leg_samples if s.complete]


_NUMBER = re.compile(r"\d+(?:\.\d+)?")

#: How far from 1 a sample's quaternion norm may be (the drivers send unit quaternions; the
#: rounding of a text format moves the norm by < 1e-3): beyond it the sample is no rotation.
UNIT_QUATERNION_TOLERANCE = 1e-2


class PoseRefused(RefusedError):
    """The pose was not recorded; the message says why and what to do."""


class StreamShort(PoseRefused):
    """A stream delivered too few good samples in the window (the device may have stopped).
    ``device_trouble``: its device said why (an error, no reply); else the computer may just
    have been too busy to read it."""

    def __init__(self, message: str, device_trouble: bool = False):
        super().__init__(message)
        self.device_trouble = device_trouble


def _by_count(faults: list[str]) -> list[str]:
    """The distinct fault messages, the one that flagged most samples first (a lasting cause —
    a node's lost heartbeat, BUS-OFF, an unplugged port — before a glitch). Messages that
    differ only in their numbers ("silent for 0.6 s", "… 0.7 s") count as one, told by its
    latest instance."""
    count: Counter[str] = Counter()
    latest: dict[str, str] = {}
    for m in faults:
        key = _NUMBER.sub("#", m)
        count[key] += 1
        latest[key] = m
    return [latest[key] for key, _ in count.most_common()]


def _array(value: object, n: int) -> np.ndarray | None:
    """``value`` as a float array of shape (n,), or None when it is not one."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None
    return arr if arr.shape == (n,) else None


def checked_tracker_sample(s: TrackerSample) -> TrackerSample:
    """``s`` when its pose is usable (or it has none); otherwise a fault sample without a pose in
    its place, naming what is wrong: a position or quaternion that is missing while the other is
    there, not of shape (3,) / (4,), not finite, or a quaternion far from unit norm.

    Defence in depth behind the drivers (which flag the non-finite numbers a device sends): no
    NaN may reach a recorded pose, nor its raw samples, which the session file keeps."""
    if s.position is None and s.quaternion is None:
        return s
    problems = []
    for name, value, n in (("position", s.position, 3), ("quaternion", s.quaternion, 4)):
        arr = None if value is None else _array(value, n)
        if value is None:
            problems.append(f"no {name}")
        elif arr is None:
            problems.append(f"malformed {name} (not {n} numbers)")
        elif not np.all(np.isfinite(arr)):
            problems.append(f"non-finite {name} {np.array2string(arr, precision=4)}")
        elif n == 4 and abs(float(np.linalg.norm(arr)) - 1.0) > UNIT_QUATERNION_TOLERANCE:
            problems.append(f"quaternion of norm {np.linalg.norm(arr):.4g}, not a rotation")
    if not problems:
        return s
    fault = f"tracker sample at t = {s.t:.3f} s: {', '.join(problems)}, discarded"
    return TrackerSample(s.t, None, None, s.rms_mm, f"{s.fault}; {fault}" if s.fault else fault)


def _leg_faults(s: LegSample) -> tuple[str, ...]:
    """Why a reading set is not complete (its own faults, else what is wrong with it)."""
    if s.faults:
        return s.faults
    r = _array(s.readings, 6)
    if r is None:
        return (f"leg reading set at t = {s.t:.3f} s: not six readings",)
    legs = ", ".join(str(k + 1) for k in np.flatnonzero(~np.isfinite(r)))
    return (f"leg reading set at t = {s.t:.3f} s: no finite reading from leg {legs}",)


def _uncertainty(s: TrackerSample) -> float:
    u = s.t_uncertainty_s
    return u if math.isfinite(u) and u > 0 else 0.0


def record_pose(
    tracker: list[TrackerSample], legs: list[LegSample], window: StillWindow, t_end: float
) -> RecordedPose:
    """The recorded pose from the samples in ``[t_end − duration, t_end]``, or PoseRefused. A
    tracker sample that may have been measured before the window began (its time less its
    uncertainty) is not in it: the platform may have been moving then."""
    return pose_from_window(
        *in_window(tracker, legs, t_end - window.duration_s, t_end), window, t_end
    )


def in_window(
    tracker: list[TrackerSample], legs: list[LegSample], t0: float, t_end: float
) -> tuple[list[TrackerSample], list[LegSample]]:
    """The samples of ``[t0, t_end]`` (monotonic s). A tracker sample that may have been
    measured before ``t0`` (its time less its uncertainty) is not in it: the platform may have
    been moving then."""
    return (
        [s for s in tracker if t0 <= s.t - _uncertainty(s) and s.t <= t_end],
        [s for s in legs if t0 <= s.t <= t_end],
    )


def pose_from_window(
    tracker: list[TrackerSample], legs: list[LegSample], window: StillWindow, t_end: float
) -> RecordedPose:
    """The recorded pose from a still window's samples (all of them, flagged ones included;
    ``t_end`` its end, monotonic s), or PoseRefused: the checks of :func:`record_pose`."""
    ts_all = [checked_tracker_sample(s) for s in tracker]
    ls_all = legs
    ts = [s for s in ts_all if not s.fault and s.position is not None]
    ls = [s for s in ls_all if s.complete]
    t_faults = [s.fault or "no pose" for s in ts_all if s.fault or s.position is None]
    l_faults = [f for s in ls_all if not s.complete for f in _leg_faults(s)]
    for name, bad, n_all, faults in (
        ("tracker samples", len(ts_all) - len(ts), len(ts_all), t_faults),
        ("leg reading sets", len(ls_all) - len(ls), len(ls_all), l_faults),
    ):
        if bad and bad > window.max_fault_share * n_all:
            raise PoseRefused(
                f"a device reported a fault during the pose ({bad} of {n_all} {name} flagged): "
                + "; ".join(_by_count(faults)[:3])
                + " — fix it and record again at the same pose"
            )
    if len(ts) < window.min_tracker_samples:
        raise StreamShort(
            f"the tracker gave {len(ts)} good samples in {window.duration_s:g} s (need {window.min_tracker_samples}): "
            "is it tracking the platform's tool?"
        )
    if len(ls) < window.min_leg_samples:
        raise StreamShort(
            f"the leg encoders gave {len(ls)} good reading sets in {window.duration_s:g} s (need {window.min_leg_samples}): "
            "is the CAN bus running?"
        )
    notes = tuple(
        f"{len(ts_all) - len(ts) if kind == 'tracker' else len(ls_all) - len(ls)} flagged {kind} "
        f"sample(s) left out: {'; '.join(_by_count(f)[:2])}"
        for kind, f in (("tracker", t_faults), ("leg", l_faults))
        if f
    )
    P = np.array([s.position for s in ts])
    rot = Rotation.from_quat(np.array([s.quaternion for s in ts]), scalar_first=True)
    mean_rot = rot.mean()
    rho = np.array([s.readings for s in ls])
    # Overflow (finite samples near 1e308) is caught by the guard below, not warned about.
    with np.errstate(over="ignore", invalid="ignore"):
        position = P.mean(axis=0)
        readings = rho.mean(axis=0)
        quaternion = mean_rot.as_quat(canonical=True, scalar_first=True)  # qw ≥ 0: readable
        # Every sample was checked above; this is the last guard, before the drift checks: NaN
        # compares false, so a non-finite average would pass them, and a session cannot hold it.
        averages = {"position": position, "quaternion": quaternion, "readings": readings}
        spoiled = [name for name, v in averages.items() if not np.all(np.isfinite(v))]
        if spoiled or not math.isfinite(t_end):
            raise PoseRefused(
                f"the pose's averaged {', '.join(spoiled) or 'time'} is not a finite number: a "
                "device delivered numbers no pose can have — check the tracker and the encoders, "
                "then record again"
            )
        angle = (
            float(np.rad2deg((rot * mean_rot.inv()).magnitude().max())) * 2
        )  # spread ≈ 2 × max deviation
        pos_spread = float(np.ptp(P, axis=0).max())
        rho_spread = float(np.ptp(rho, axis=0).max())
        # Drift: second half's mean against the first half's (samples are in time order).
        h_t, h_l = len(ts) // 2, len(ls) // 2
        pos_drift = float(np.abs(P[h_t:].mean(axis=0) - P[:h_t].mean(axis=0)).max())
        ang_drift = float(np.rad2deg((rot[h_t:].mean() * rot[:h_t].mean().inv()).magnitude()))
        leg_drift = np.abs(rho[h_l:].mean(axis=0) - rho[:h_l].mean(axis=0))
    # "not <=" rather than ">": a drift that is not a number is no proof of stillness.
    if not (pos_drift <= window.max_position_drift_mm and ang_drift <= window.max_angle_drift_deg):
        raise PoseRefused(
            f"the platform moved during the pose (drifted {pos_drift:.3f} mm, {ang_drift:.4f} deg "
            f"within the window; allowed {window.max_position_drift_mm} mm, "
            f"{window.max_angle_drift_deg} deg): hold it still and record again"
        )
    if not np.all(leg_drift <= window.max_reading_drift_mm):
        leg = int(np.argmax(np.where(np.isnan(leg_drift), np.inf, leg_drift))) + 1
        raise PoseRefused(
            f"leg {leg} moved during the pose (drifted {leg_drift[leg - 1]:.4f} mm within the "
            f"window, allowed {window.max_reading_drift_mm} mm): wait for the legs to settle and "
            "record again"
        )
    return RecordedPose(
        t=t_end,
        position=position,
        quaternion=quaternion,
        readings=readings,
        tracker_samples=ts_all,
        leg_samples=ls_all,
        position_spread_mm=pos_spread,
        angle_spread_deg=angle,
        reading_spread_mm=rho_spread,
        alignment_s=float(np.mean([s.t for s in ts]) - np.mean([s.t for s in ls])),
        notes=notes,
    )


class Acquisition:
    """Reads both sources in background threads into time-stamped buffers; :meth:`record`
    waits out a still window (and up to ``late_s`` for samples measured in it to arrive) and
    returns the recorded pose (or raises PoseRefused).

    A window starts when :meth:`record` is called, unless a motion controller said when the
    platform came to rest (:meth:`anchor`): then it starts there, or where the last window
    ended if that is later, even when the request comes after it — the samples are buffered —,
    so what is recorded does not depend on when the operator pressed the key."""

    #: How many more still windows :meth:`record` takes when a stream came short while its
    #: device showed nothing wrong (no error, not waiting on it): the computer was too busy to
    #: read it in time. A window's samples are never padded or stretched: a whole new one.
    short_retries: int = 2

    def __init__(
        self,
        tracker: PoseSource,
        legs: LegSource,
        window: StillWindow = StillWindow(),
        clock: Callable[[], float] = time.monotonic,
        buffer_s: float = 10.0,
        late_s: float = 0.1,
    ):
        self.tracker, self.legs, self.window, self.clock = tracker, legs, window, clock
        self.late_s = late_s  #: how long record() waits for samples measured before the end
        self._tbuf: deque[TrackerSample] = deque()
        self._lbuf: deque[LegSample] = deque()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._errors: deque[tuple[float, str]] = deque(maxlen=20)  # (time, what a device raised)
        #: Per stream, since when its thread has waited for the device's next sample (None: not).
        self._waiting: dict[str, float | None] = {}
        self.buffer_s = buffer_s
        #: Where the next window starts, per stream (tracker, legs; clock s), once a motion
        #: controller said when the platform came to rest (:meth:`anchor`); else None.
        self._next: tuple[float, float] | None = None

    def _pump(self, source: PoseSource | LegSource, buf: deque[Any], name: str) -> None:
        while not self._stop.is_set():
            self._waiting[name] = self.clock()
            try:
                s = source.sample()
            except Exception as exc:  # a device failing must not kill acquisition silently
                self._errors.append((self.clock(), f"{name}: {exc}"))
                s = (
                    TrackerSample(self.clock(), None, None, fault=f"{name}: {exc}")
                    if name == "tracker"
                    else LegSample(self.clock(), np.full(6, np.nan), (f"{name}: {exc}",))
                )
                self._stop.wait(0.05)
            self._waiting[name] = None
            with self._lock:
                buf.append(s)
                while buf and buf[0].t < s.t - self.buffer_s:
                    buf.popleft()

    def start(self) -> Acquisition:
        self._stop.clear()
        for src, buf, name in (
            (self.tracker, self._tbuf, "tracker"),
            (self.legs, self._lbuf, "leg encoders"),
        ):
            th = threading.Thread(
                target=self._pump, args=(src, buf, name), name=f"hexcal-{name}", daemon=True
            )
            th.start()
            self._threads.append(th)
        return self

    def stop(self) -> None:
        self._stop.set()
        for th in self._threads:
            th.join(timeout=2.0)
        self._threads.clear()

    def __enter__(self) -> Acquisition:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def latest(self) -> tuple[TrackerSample | None, LegSample | None]:
        with self._lock:
            return (self._tbuf[-1] if self._tbuf else None), (
                self._lbuf[-1] if self._lbuf else None
            )

    def anchor(self, t: float) -> None:
        """The platform came to rest at ``t`` (s, on :attr:`clock`), as a motion controller
        reports: the next still window starts there (see the class docstring). A rig without
        a motion controller never calls this: its windows start at the request."""
        with self._lock:
            self._next = (t, t)

    def _window_start(self) -> tuple[float, float]:
        """Where the next still window starts, per stream (tracker, legs; s on :attr:`clock`)."""
        now = self.clock()
        with self._lock:
            start = self._next
        # The buffers hold buffer_s of samples: a window older than that is gone.
        if start is None or min(start) < now - self.buffer_s + 3 * self.window.duration_s:
            return now, now
        return start

    def record(self) -> RecordedPose:
        """Wait one still window from now and record the pose from it. A window in which a
        stream came short with nothing wrong with its device is taken again (at most
        :attr:`short_retries` times; the platform stands still meanwhile), logged at info
        level and said in the pose's ``notes``."""
        short: list[str] = []
        while True:
            try:
                pose = self._record_window()
            except StreamShort as exc:
                if exc.device_trouble or len(short) >= self.short_retries:
                    if short:
                        raise StreamShort(
                            f"{exc} ({len(short) + 1} windows in a row came short)"
                        ) from None
                    raise
                short.append(str(exc))
                log.info("%s — taking the window again (a busy computer?)", exc)
                continue
            if short:
                pose.notes = (
                    *pose.notes,
                    f"still window taken {len(short) + 1} times, the earlier ones came short: "
                    + "; ".join(short),
                )
            return pose

    def _record_window(self) -> RecordedPose:
        starts = self._window_start()
        if self.window.counted:
            ts, ls, t_end = self._counted_window(*starts)
        else:
            ts, ls, t_end = self._timed_window(starts[0])
        try:
            if len(ts) < (self.window.tracker_samples or 0):
                raise StreamShort(
                    f"the tracker gave {len(ts)} of {self.window.tracker_samples} samples in time: is it tracking the platform's tool?"
                )
            if len(ls) < (self.window.leg_samples or 0):
                raise StreamShort(
                    f"the leg encoders gave {len(ls)} of {self.window.leg_samples} reading sets in time: is the CAN bus running?"
                )
            return pose_from_window(ts, ls, self.window, t_end)
        except StreamShort as exc:
            raise self._short(exc, min(starts)) from None

    def _timed_window(self, t_start: float) -> tuple[list[TrackerSample], list[LegSample], float]:
        """Every sample measured in ``[t_start, t_start + duration_s]`` (see :func:`record_pose`)
        and the window's end."""
        t_end = t_start + self.window.duration_s
        with self._lock:
            if self._next is not None:
                self._next = (t_end, t_end)
        while self.clock() < t_end:
            time.sleep(min(0.01, max(t_end - self.clock(), 0.0)))
        # Samples are stamped with their measurement instant and arrive a little later (a
        # reading set once the set closes): wait, briefly, until both streams are past t_end.
        give_up = t_end + self.late_s
        while self.clock() < give_up:
            with self._lock:
                if self._tbuf and self._lbuf and min(self._tbuf[-1].t, self._lbuf[-1].t) >= t_end:
                    break
            time.sleep(0.005)
        with self._lock:
            ts, ls = in_window(list(self._tbuf), list(self._lbuf), t_start, t_end)
        return ts, ls, t_end

    def _counted_window(
        self, t_tracker: float, t_legs: float
    ) -> tuple[list[TrackerSample], list[LegSample], float]:
        """The first ``tracker_samples`` tracker samples measured from ``t_tracker`` and the
        first ``leg_samples`` reading sets from ``t_legs`` (fewer when they do not come within
        ``3 × duration_s``), and the window's end: its last sample's time."""
        n_t, n_l = self.window.tracker_samples or 0, self.window.leg_samples or 0
        give_up = max(t_tracker, t_legs) + 3 * self.window.duration_s + self.late_s
        while True:
            with self._lock:
                ts = [s for s in self._tbuf if s.t - _uncertainty(s) >= t_tracker][:n_t]
                ls = sorted((s for s in self._lbuf if s.t >= t_legs), key=lambda s: s.t)[:n_l]
            if (len(ts) == n_t and len(ls) == n_l) or self.clock() > give_up:
                break
            time.sleep(0.005)
        # The next window at this pose goes on from the samples after these.
        ends = (ts[-1].t + 1e-9 if ts else t_tracker, ls[-1].t + 1e-9 if ls else t_legs)
        with self._lock:
            if self._next is not None:
                self._next = ends
        return ts, ls, max(ends)

    def _short(self, exc: StreamShort, t_start: float) -> StreamShort:
        """``exc``, or, when a device stopped answering, the same with what it last raised:
        such a device leaves no sample in the window to name the fault, and what it said (a
        timeout, a lost port) says more than the count."""
        now = self.clock()
        stalled = [
            f"the {name} {'have' if name.endswith('s') else 'has'} not answered for "
            f"{now - since:.1f} s (waiting for a reply)"
            for name, since in self._waiting.items()
            if since is not None and now - since > self.window.duration_s / 2
        ]
        recent = [f"the device said: {m}" for t, m in list(self._errors) if t >= t_start - 2.0]
        if stalled or recent:
            return StreamShort(" — ".join([str(exc), *stalled, *recent[-1:]]), device_trouble=True)
        return exc
