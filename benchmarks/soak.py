"""Soak test of the mock rig at the full mock rate: zero frames dropped, memory flat.

    python benchmarks/soak.py --seconds 60 [--sync-period-ms 1] [--json out.json]

The rig is the one ``hexcal devices check --mock`` builds (:func:`hexcal.acquire.devices_check.mock_rig`),
assembled here by hand so the soak can watch the mock side too: one
:class:`~hexcal.mock_hw.robot.MockRobot`, a mock NDI tracker registered under a fresh name and
reached as ``ndimock://NAME``, and six :class:`~hexcal.mock_hw.can_encoders.MockEncoderNodes` on
python-can's virtual bus. The real drivers read them through their real transports and the real
acquisition threads: :class:`hexcal.acquire.acquisition.Acquisition` pumps
``NDITracker.sample(binary=True)`` (continuous polling; the mock makes a new frame at 60 Hz) and
``LegEncoders.read_set()`` (SYNC produced by the driver at ``--sync-period-ms``). Meanwhile a
motion thread moves the robot to a small random pose about home every ``--move-period-s``, and
every ``--record-period-s`` the soak does what an operator does: stop moving, let it settle,
``Acquisition.record()``.

Measured (printed as one JSON document, also written to ``--json``):

- CAN: SYNCs expected, sent (driver) and seen (mock); position TPDO frames sent by the mock and received
  by the driver (the difference, less what was still queued at stop, is frames dropped); reading
  sets produced and read; sets with a position missing when they closed versus sets flagged only
  for lateness, told apart by the fault texts of ``drivers/can_encoders.py``; every position
  compared with the reading the mock latched at *that* set's SYNC (a late position kept, unflagged,
  in a set marked complete shows up here and nowhere else); the ``ReadingSet.index`` sequence,
  which must never skip; the TPDO delay after its SYNC (histogram).
- Tracker: polls, new frames, gaps in the tracker's frame numbers (missed frames), CRC and
  format errors, faulted samples, reply latency.
- Acquisition: moves, record() attempts, poses recorded, refusals by reason.
- Memory: VmRSS (``/proc/self/status``) and ``tracemalloc`` every ``--sample-period-s``; a
  linear fit over the second half of the run; the lengths of the containers of the rig that keep
  history (mock logs, acquisition buffers, driver queues, virtual-bus queues), each with its
  bound, bytes per entry and growth per minute, so growth is attributed; with ``--attribute``, a
  tracemalloc snapshot diff by source line between the middle and the end of the run (a
  snapshot stalls every thread for a moment, so it is off by default).
- CPU: process CPU time over wall time, per thread; and the CPU other processes used and the
  hypervisor stole meanwhile (timing figures mean little on a busy or shared machine).

tracemalloc slows every allocation (here about 2–3×) and so the timing figures; run with
``--no-tracemalloc`` for timing, and with it (the default) for the memory attribution.

Observation hooks (this script only; no project file is changed): the tracker's
``poll_binary`` and the mock nodes' ``_send`` are wrapped *on the instances* to count polls,
frame numbers and frames sent; the mock's ``history`` is read (under its lock) to check values.

Exit status 0 unless ``--check`` is given and a frame was dropped or memory was not flat.
"""

# ruff: noqa: E402  (the BLAS thread count is set before numpy is imported)
from __future__ import annotations

import os

from hexcal.app.cli import single_thread_blas

# As the CLI does: one BLAS thread; the rig's threads already share two cores.
single_thread_blas()

import argparse
import json
import platform
import re
import sys
import threading
import time
import tracemalloc
import uuid
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import can
import numpy as np
from can.interfaces import virtual as can_virtual
from scipy.spatial.transform import Rotation

from hexcal.acquire.acquisition import Acquisition, LegSample, PoseRefused, TrackerSample
from hexcal.drivers.can_config import SYNC_COB_ID, CanBusConfig, default_can_config
from hexcal.drivers.can_encoders import EncoderError, LegEncoders, ReadingSet
from hexcal.drivers.ndi import (
    NDITracker,
    TrackerCRCError,
    TrackerError,
    TrackerFormatError,
    TrackerFrame,
    TrackerTimeout,
)
from hexcal.mock_hw.can_encoders import MockEncoderNodes
from hexcal.mock_hw.ndi_registry import register_robot, unregister
from hexcal.mock_hw.ndi_tracker import MockNDITracker
from hexcal.mock_hw.robot import MockRobot
from hexcal.sim.robots import left_hand

#: How "memory flat" is judged (also written into the JSON).
FLAT_DEFINITION = (
    "over the second half of the run: the least-squares slope of VmRSS is below "
    "{rss_pct:g} % of the mean VmRSS per minute, and tracemalloc's current size grew by less "
    "than {tm_mb:g} MB (last sample minus the sample nearest the middle)"
)

#: Fault texts of drivers/can_encoders.py, by kind (the driver's keys are not exposed).
FAULT_PATTERNS: dict[str, re.Pattern[str]] = {
    "missing": re.compile(r"sent no position for SYNC"),
    "late": re.compile(r"position arrived [\d.]+ ms after SYNC"),
    "twice": re.compile(r"sent two positions for SYNC"),
    "sync_stall": re.compile(r"stalled and skipped (\d+) SYNCs"),
    "silent": re.compile(r"silent for [\d.]+ s"),
    "nmt": re.compile(r"reports NMT state"),
    "error_frame": re.compile(r"CAN error frame"),
    "discarded": re.compile(r"were discarded unread"),
    "off_clock": re.compile(r"sent a position stamped [-+\d.]+ s off the clock"),
    "clock_jump": re.compile(r"jumped [-+\d.]+ s"),
    "non_finite": re.compile(r"non-finite|not a finite"),
}

#: What the mock latched at a SYNC it has not handled yet (see :class:`LegProbe`).
PENDING = "pending"

#: How the driver names a leg in a fault text: "leg 3 encoder (node 0x23)".
LEG_NAME = re.compile(r"leg (\d) encoder")

#: Histogram of TPDO delay after its SYNC: 0.1 ms bins up to 20 ms, the last bin is ">= 20 ms".
DELAY_BIN_MS = 0.1
DELAY_BINS = 201


# -- configuration ------------------------------------------------------------------------------
@dataclass
class SoakConfig:
    """What to run: duration, SYNC timing, operator behaviour, what to measure."""

    seconds: float = 60.0
    sync_period_ms: float = 10.0
    max_tpdo_delay_ms: float | None = None  #: None: the config default (half the SYNC period)
    move_period_s: float = 0.1
    move_mm: float = 1.0  #: half-width of the uniform position perturbation about home, mm
    move_deg: float = 0.1  #: half-width of the rotation perturbation about home, deg
    record_period_s: float = 3.0
    settle_s: float = 0.05  #: pause between the last move and record() (one tracker frame is 17 ms)
    sample_period_s: float = 5.0
    seed: int = 0
    trace: bool = True  #: run tracemalloc (slows allocation; the RSS is measured either way)
    attribute: bool = False  #: tracemalloc snapshot diff, middle vs end (stalls threads briefly)
    switch_interval_ms: float | None = None  #: sys.setswitchinterval for the run (None: leave it)
    flat_rss_pct_per_min: float = 1.0
    flat_tracemalloc_mb: float = 1.0


# -- small measurement helpers --------------------------------------------------------------------
def system_cpu() -> dict[str, float] | None:
    """Whole-machine CPU time so far, s (Linux ``/proc/stat``): busy (user, nice, system, irq,
    softirq) and steal (time the hypervisor gave the virtual CPUs to someone else)."""
    try:
        with open("/proc/stat") as fh:
            v = [int(x) for x in fh.readline().split()[1:]]
    except (OSError, ValueError):
        return None
    tick = os.sysconf("SC_CLK_TCK")
    # user nice system idle iowait irq softirq steal (guest time is already in user)
    busy = v[0] + v[1] + v[2] + sum(v[5:7])
    steal = v[7] if len(v) > 7 else 0
    return {"busy_s": busy / tick, "steal_s": steal / tick}


def loadavg() -> float | None:
    """The 1-minute load average, None where the system has none."""
    try:
        return round(os.getloadavg()[0], 2)
    except (OSError, AttributeError):
        return None


def rss_kb() -> int | None:
    """VmRSS of this process in kB (Linux), None elsewhere."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def thread_cpu_s() -> dict[str, float]:
    """CPU time (user + system, s) of each live Python thread, by thread name (Linux)."""
    tick = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    out: dict[str, float] = {}
    for th in threading.enumerate():
        tid = th.native_id
        if tid is None:
            continue
        try:
            with open(f"/proc/self/task/{tid}/stat") as fh:
                fields = fh.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        # After the ")" that ends comm: state is field 3, utime 14 and stime 15 (1-based).
        out[th.name] = out.get(th.name, 0.0) + (int(fields[11]) + int(fields[12])) / tick
    return out


def deep_size(obj: object) -> int:
    """Bytes held by ``obj`` and, recursively, by the items of tuples and lists (numpy arrays
    that own their data count it): enough for the entries of the containers watched here."""
    size = sys.getsizeof(obj)
    if isinstance(obj, (tuple, list)):
        size += sum(deep_size(x) for x in obj)
    return size


def linear_slope(t_s: list[float], y: list[float]) -> float | None:
    """Least-squares slope of ``y`` against ``t_s`` (s), per minute; None with < 2 points."""
    if len(t_s) < 2 or len({round(t, 6) for t in t_s}) < 2:
        return None
    return float(np.polyfit(np.asarray(t_s) / 60.0, np.asarray(y, float), 1)[0])


# -- sources: the real drivers behind the acquisition's interfaces -------------------------------
class TrackerProbe:
    """The acquisition's ``PoseSource``: ``NDITracker.sample(binary=True)``, counting what goes by.

    ``NDITracker.sample`` polls until the frame number changes; its ``poll_binary`` is wrapped
    on the instance to see every polled frame's number (gaps = frames missed) and every link
    error (CRC, format, timeout), which are then re-raised unchanged.
    """

    def __init__(self, tracker: NDITracker):
        self.tracker = tracker
        self.polls = 0
        self.new_frames = 0
        self.frame_gaps = 0  #: times the frame number advanced by more than 1
        self.frames_missed = 0  #: frame numbers skipped in total
        self.frames_backwards = 0
        self.no_frame_number = 0
        self.largest_gap = 0
        self.gap_examples: list[dict[str, float]] = []
        self.first_frame: int | None = None
        self.last_frame: int | None = None
        self.errors: dict[str, int] = {"crc": 0, "format": 0, "timeout": 0, "other": 0}
        self.error_examples: list[str] = []
        self.samples = 0
        self.fault_samples = 0
        self.fault_examples: list[str] = []
        self._t0 = time.monotonic()
        self._poll = tracker.poll_binary
        tracker.poll_binary = self._counting_poll  # type: ignore[method-assign]

    def _counting_poll(self) -> TrackerFrame:
        try:
            frame = self._poll()
        except TrackerError as exc:
            kind = (
                "crc"
                if isinstance(exc, TrackerCRCError)
                else "format"
                if isinstance(exc, TrackerFormatError)
                else "timeout"
                if isinstance(exc, TrackerTimeout)
                else "other"
            )
            self.errors[kind] += 1
            if len(self.error_examples) < 5:
                self.error_examples.append(f"{type(exc).__name__}: {exc}")
            raise
        self.polls += 1
        number = frame.frame_number
        if number is None:
            self.no_frame_number += 1
            return frame
        last = self.last_frame
        if last is None:
            self.first_frame = number
            self.new_frames += 1
        elif number != last:
            self.new_frames += 1
            if number < last:
                self.frames_backwards += 1
            elif number > last + 1:
                self.frame_gaps += 1
                self.frames_missed += number - last - 1
                self.largest_gap = max(self.largest_gap, number - last - 1)
                if len(self.gap_examples) < 10:
                    self.gap_examples.append(
                        {
                            "t_s": round(frame.received_at - self._t0, 3),
                            "after_frame": last,
                            "missed": number - last - 1,
                        }
                    )
        self.last_frame = number
        return frame

    def sample(self) -> TrackerSample:
        """The next new tracker frame as a sample (``PoseSource``), counted."""
        s = self.tracker.sample(binary=True)
        self.samples += 1
        if s.fault:
            self.fault_samples += 1
            if len(self.fault_examples) < 5:
                self.fault_examples.append(s.fault)
        return s

    def summary(self, wall_s: float, frame_rate_hz: float) -> dict[str, Any]:
        """What was counted, for the JSON summary."""
        lat = self.tracker.latency_stats()
        span = (
            self.last_frame - self.first_frame + 1
            if self.first_frame is not None and self.last_frame is not None
            else 0
        )
        return {
            "polls": self.polls,
            "polls_per_s": round(self.polls / wall_s, 1),
            "new_frames_seen": self.new_frames,
            "frame_numbers_spanned": span,
            "expected_frames_at_rate": round(wall_s * frame_rate_hz),
            "frame_gaps": self.frame_gaps,
            "frames_missed": self.frames_missed,
            "largest_gap_frames": self.largest_gap,
            "gap_examples": self.gap_examples,
            "frames_backwards": self.frames_backwards,
            "frames_without_number": self.no_frame_number,
            "crc_errors": self.errors["crc"],
            "format_errors": self.errors["format"],
            "timeouts": self.errors["timeout"],
            "other_link_errors": self.errors["other"],
            "link_error_examples": self.error_examples,
            "samples": self.samples,
            "fault_samples": self.fault_samples,
            "fault_examples": self.fault_examples,
            "reply_latency_last_50_polls_ms": {
                k.removesuffix("_s"): (round(v * 1e3, 3) if k != "n" else v) for k, v in lat.items()
            },
            "timing_warning": self.tracker.timing_warning,
        }


class LegProbe:
    """The acquisition's ``LegSource``: ``LegEncoders.read_set()`` as ``LegEncoders.sample()``
    does it (same timeout, same ``to_leg_sample``), but seeing the ReadingSet first: its
    ``index`` (must never skip), its faults by kind, its TPDO delays, and — with ``latched`` —
    whether each position is the one the mock node latched at *that* SYNC.

    ``latched(index)`` returns (SYNC counter, readings (6,) mm) the mock latched at the
    ``index``-th SYNC, :data:`PENDING` when the mock has not handled that SYNC yet (so any
    position in the set answers an earlier one), or None when it is no longer known.
    """

    def __init__(
        self,
        encoders: LegEncoders,
        latched: Callable[[int], tuple[int, np.ndarray] | str | None] | None = None,
    ):
        self.encoders = encoders
        self.latched = latched
        cfg = encoders.config
        self.timeout = max(1.0, 3 * cfg.sync_period_s, cfg.heartbeat_timeout_s)
        self._cpm = np.array([leg.counts_per_mm for leg in cfg.legs])
        self._sign = np.array([leg.sign for leg in cfg.legs], float)
        self._zero = np.array([leg.zero_mm for leg in cfg.legs])
        self.sets = 0
        self.complete = 0
        self.flagged = 0
        self.with_missing = 0  #: at least one position absent when the set closed
        self.late_only = 0  #: every fault is "late": all six arrived, one or more after the limit
        self.late_twice_only = 0  #: only "late" and "sent two positions" faults
        self.other_flagged = 0
        self.fault_counts: dict[str, int] = {}
        self.fault_examples: dict[str, str] = {}
        self.syncs_skipped_by_stalls = 0
        self.missing_positions = [0] * 6  #: per leg, positions absent from their set
        self.duplicate_positions = [0] * 6  #: per leg, "sent two positions" faults
        self.index_gaps = 0
        self.index_examples: list[tuple[int, int]] = []
        self.first_index: int | None = None
        self.last_index: int | None = None
        self.max_sync_interval_ms = 0.0
        self.min_sync_interval_ms = float("inf")
        self._last_t_sync: float | None = None
        self._prev_missing = False
        self.delay_hist = np.zeros(DELAY_BINS, np.int64)
        self.max_delay_ms = 0.0
        # Positions checked against the mock's latched readings.
        self.positions_checked = 0
        self.sets_unverifiable = 0  #: latched entry forgotten, or its SYNC counter differs
        self.wrong_before_latch = 0  #: positions in sets whose SYNC the mock had not handled yet
        self.wrong_in_complete = 0  #: positions not from their own SYNC, in sets marked complete
        self.wrong_in_flagged = 0  #: the same, in flagged sets
        self.stale_by_one = 0  #: wrong positions equal to the previous SYNC's latched reading
        self.wrong_complete_sets = 0  #: sets marked complete holding a wrong position
        self.wrong_complete_after_missing = 0  #: ... whose previous set had a position missing
        self.wrong_examples: list[dict[str, Any]] = []

    def _counts(self, mm: np.ndarray) -> np.ndarray:
        """Readings (6,) mm as the counts the nodes sent (the driver's conversion inverted)."""
        return np.rint((mm - self._zero) * self._cpm * self._sign)

    def _verify(self, rs: ReadingSet) -> None:
        """Compare each position with what the mock latched at this set's SYNC."""
        if self.latched is None:
            return
        own = self.latched(rs.index)
        have = np.isfinite(rs.readings_mm)
        got = self._counts(np.where(have, rs.readings_mm, 0.0))
        if isinstance(own, str):  # PENDING: every position here answers an earlier SYNC
            wrong = have
            self.wrong_before_latch += int(have.sum())
        elif own is None or own[0] != rs.sync_counter:
            self.sets_unverifiable += 1
            return
        else:
            wrong = have & (got != self._counts(own[1]))
        self.positions_checked += int(have.sum())
        n_wrong = int(wrong.sum())
        if not n_wrong:
            return
        if rs.complete:
            self.wrong_in_complete += n_wrong
            self.wrong_complete_sets += 1
            self.wrong_complete_after_missing += self._prev_missing
        else:
            self.wrong_in_flagged += n_wrong
        prev = self.latched(rs.index - 1) if rs.index > 0 else None
        if prev is not None and not isinstance(prev, str):
            self.stale_by_one += int((wrong & (got == self._counts(prev[1]))).sum())
        if len(self.wrong_examples) < 10 and (rs.complete or len(self.wrong_examples) < 5):
            self.wrong_examples.append(
                {
                    "index": rs.index,
                    "complete": rs.complete,
                    "legs": [k + 1 for k in np.flatnonzero(wrong).tolist()],
                    "faults": [f[:90] for f in rs.faults[:3]],
                }
            )

    def check(self, rs: ReadingSet) -> None:
        """Account for one reading set."""
        self.sets += 1
        if self.last_index is None:
            self.first_index = rs.index
        elif rs.index != self.last_index + 1:
            self.index_gaps += 1
            if len(self.index_examples) < 10:
                self.index_examples.append((self.last_index, rs.index))
        self.last_index = rs.index
        if self._last_t_sync is not None:
            gap_ms = (rs.t_sync - self._last_t_sync) * 1e3
            self.max_sync_interval_ms = max(self.max_sync_interval_ms, gap_ms)
            self.min_sync_interval_ms = min(self.min_sync_interval_ms, gap_ms)
        self._last_t_sync = rs.t_sync
        delays = (rs.arrival - rs.t_sync) * 1e3
        delays = delays[np.isfinite(delays)]
        if delays.size:
            self.max_delay_ms = max(self.max_delay_ms, float(delays.max()))
            bins = np.minimum((np.maximum(delays, 0.0) / DELAY_BIN_MS).astype(np.int64), 200)
            self.delay_hist += np.bincount(bins, minlength=DELAY_BINS)
        self._verify(rs)
        self._prev_missing = bool(np.isnan(rs.readings_mm).any())
        if rs.complete:
            self.complete += 1
            return
        self.flagged += 1
        kinds: dict[str, int] = {}
        for text in rs.faults:
            kind = "other"
            for name, pat in FAULT_PATTERNS.items():
                m = pat.search(text)
                if m:
                    kind = name
                    if name == "sync_stall":
                        self.syncs_skipped_by_stalls += int(m.group(1))
                    elif name in ("missing", "twice"):
                        leg = LEG_NAME.search(text)
                        if leg:
                            counts = (
                                self.missing_positions
                                if name == "missing"
                                else self.duplicate_positions
                            )
                            counts[int(leg.group(1)) - 1] += 1
                    break
            kinds[kind] = kinds.get(kind, 0) + 1
            self.fault_examples.setdefault(kind, text)
        for kind, n in kinds.items():
            self.fault_counts[kind] = self.fault_counts.get(kind, 0) + n
        if "missing" in kinds:
            self.with_missing += 1
        elif set(kinds) == {"late"}:
            self.late_only += 1
        elif set(kinds) <= {"late", "twice"}:
            self.late_twice_only += 1
        else:
            self.other_flagged += 1

    def sample(self) -> LegSample:
        """The next reading set as a sample (``LegSource``), checked."""
        rs = self.encoders.read_set(timeout=self.timeout)
        self.check(rs)
        return rs.to_leg_sample()

    def drain(self) -> int:
        """After the driver stopped: read (and check) the sets still queued; how many."""
        n = 0
        while True:
            try:
                rs = self.encoders.read_set(timeout=0.0)
            except EncoderError:
                return n
            self.check(rs)
            n += 1

    def delay_percentiles_ms(self) -> dict[str, float | None]:
        """TPDO delay after SYNC (bin upper edges, ms; None beyond the histogram's 20 ms):
        p50, p99, p99.9, and the exact max."""
        total = int(self.delay_hist.sum())
        if not total:
            return {}
        cum = np.cumsum(self.delay_hist)
        out: dict[str, float | None] = {}
        for name, q in (("p50", 0.5), ("p99", 0.99), ("p99.9", 0.999)):
            b = int(np.searchsorted(cum, q * total))
            out[name] = round((b + 1) * DELAY_BIN_MS, 1) if b < DELAY_BINS - 1 else None
        out["max"] = round(self.max_delay_ms, 3)
        return out


# -- the operator -----------------------------------------------------------------------------------
class Mover(threading.Thread):
    """Moves the robot to a random pose near home every ``period_s`` unless paused."""

    def __init__(self, robot: MockRobot, cfg: SoakConfig):
        super().__init__(name="soak-mover", daemon=True)
        self.robot = robot
        self.cfg = cfg
        self.rng = np.random.default_rng([cfg.seed, 0x50AC])
        self.home_p = np.asarray(robot.truth.home.position, float)
        self.home_r = Rotation.from_quat(robot.truth.home.quaternion, scalar_first=True)
        self.moves = 0
        self.stop_evt = threading.Event()
        self.lock = threading.Lock()  #: held while moving; the recorder takes it to pause motion

    def move_once(self) -> None:
        """One small random move about home (bounded: never a random walk)."""
        dp = self.rng.uniform(-1.0, 1.0, 3) * self.cfg.move_mm
        dr = Rotation.from_rotvec(np.deg2rad(self.rng.uniform(-1.0, 1.0, 3) * self.cfg.move_deg))
        self.robot.move_to(self.home_p + dp, (dr * self.home_r).as_matrix())
        self.moves += 1

    def run(self) -> None:
        next_t = time.monotonic()
        while not self.stop_evt.is_set():
            with self.lock:
                self.move_once()
            next_t += self.cfg.move_period_s
            now = time.monotonic()
            if next_t < now:  # held still by the recorder: resume the rhythm, do not catch up
                next_t = now
            self.stop_evt.wait(max(0.0, next_t - time.monotonic()))


# -- the soak ---------------------------------------------------------------------------------------
class Sampler(threading.Thread):
    """Every ``period_s``: RSS, tracemalloc, CPU, watched container lengths, bus backlogs."""

    def __init__(self, period_s: float, probe: Callable[[], dict[str, Any]]):
        super().__init__(name="soak-sampler", daemon=True)
        self.period_s = period_s
        self.probe = probe
        self.series: list[dict[str, Any]] = []
        self.stop_evt = threading.Event()

    def take(self) -> None:
        """One sample now."""
        self.series.append(self.probe())

    def run(self) -> None:
        next_t = time.monotonic() + self.period_s
        while not self.stop_evt.wait(max(0.0, next_t - time.monotonic())):
            self.take()
            next_t += self.period_s


@dataclass
class Watched:
    """A container that could grow during a soak: how to reach it, where it is defined, and
    whether its length is bounded by time rather than by a maxlen."""

    label: str
    get: Callable[[], Any]
    where: str
    time_bounded: str = ""


def _attr(obj: object, *names: str) -> Callable[[], Any]:
    """A getter for ``obj.names[0].names[1]...``, None when an attribute is absent (the mocks
    and drivers change; a missing container is reported as absent, not an error)."""

    def get() -> Any:
        cur: Any = obj
        for n in names:
            cur = getattr(cur, n, None)
            if cur is None:
                return None
        return cur

    return get


def watch_list(
    robot: MockRobot,
    nodes: MockEncoderNodes,
    device: MockNDITracker,
    trk: NDITracker,
    enc: LegEncoders,
    acq: Acquisition,
) -> list[Watched]:
    """The containers of the rig that hold history, mock side and driver side."""
    buf = f"trimmed to the last buffer_s = {acq.buffer_s:g} s"
    return [
        Watched("MockRobot._poses", _attr(robot, "_poses"), "mock_hw/robot.py (one per move_to)"),
        Watched(
            "MockRobot.encoder_latches",
            _attr(robot, "encoder_latches"),
            "mock_hw/robot.py (one per encoder latch = per SYNC)",
        ),
        Watched(
            "MockEncoderNodes.history",
            _attr(nodes, "history"),
            "mock_hw/can_encoders.py (one per SYNC)",
        ),
        Watched(
            "MockEncoderNodes.nmt_log",
            _attr(nodes, "nmt_log"),
            "mock_hw/can_encoders.py (one per NMT command)",
        ),
        Watched(
            "MockEncoderNodes._scheduled",
            _attr(nodes, "_scheduled"),
            "mock_hw/can_encoders.py (delayed TPDOs)",
        ),
        Watched(
            "MockNDITracker.commands",
            _attr(device, "commands"),
            "mock_hw/ndi_tracker.py (one per command)",
        ),
        Watched(
            "MockNDITracker.frame_times",
            _attr(device, "frame_times"),
            "mock_hw/ndi_tracker.py (one per tracker frame)",
        ),
        Watched(
            "MockNDITracker._pending",
            _attr(device, "_pending"),
            "mock_hw/ndi_tracker.py (replies in flight)",
        ),
        Watched("NDITracker._latencies", _attr(trk, "_latencies"), "drivers/ndi.py (per poll)"),
        Watched(
            "NDITracker.frame_clock._lo",
            _attr(trk, "frame_clock", "_lo"),
            "drivers/ndi_clock.py FrameClock (per poll)",
            "trimmed to window_s / max_frames",
        ),
        Watched(
            "NDITracker.frame_clock._hi",
            _attr(trk, "frame_clock", "_hi"),
            "drivers/ndi_clock.py FrameClock (per new frame)",
            "trimmed to window_s / max_frames",
        ),
        Watched(
            "NDITracker.frame_clock._own",
            _attr(trk, "frame_clock", "_own"),
            "drivers/ndi_clock.py FrameClock (per new frame)",
        ),
        Watched("LegEncoders._queue", _attr(enc, "_queue"), "drivers/can_encoders.py"),
        Watched(
            "Acquisition._tbuf",
            _attr(acq, "_tbuf"),
            "src/hexcal/acquire/acquisition.py (tracker)",
            buf,
        ),
        Watched(
            "Acquisition._lbuf",
            _attr(acq, "_lbuf"),
            "src/hexcal/acquire/acquisition.py (legs)",
            buf,
        ),
        Watched("Acquisition._errors", _attr(acq, "_errors"), "src/hexcal/acquire/acquisition.py"),
    ]


def summarize_containers(
    series: list[dict[str, Any]], watched: list[Watched], half_s: float, wall_s: float
) -> dict[str, dict[str, Any]]:
    """Per watched container: length at start, middle and end, growth per minute over the
    second half (least squares), bytes per entry (the last entry, deep to one nesting level),
    its bound, and a verdict."""
    info_of = {w.label: w for w in watched}
    mid = _nearest(series, half_s)
    out: dict[str, dict[str, Any]] = {}
    for key in series[-1]["lengths"]:
        if series[-1]["lengths"][key] is None:
            out[key] = {"verdict": "absent in this version", "where": info_of[key].where}
            continue
        pts = [
            (s["t_s"], s["lengths"][key])
            for s in series
            if s["t_s"] >= half_s and s["lengths"].get(key) is not None
        ]
        slope = linear_slope([p[0] for p in pts], [p[1] for p in pts])
        w = info_of.get(key)
        c = w.get() if w else None
        cap = getattr(c, "maxlen", None)
        end = series[-1]["lengths"][key]
        info: dict[str, Any] = {
            "start": series[0]["lengths"].get(key),
            "middle": mid["lengths"].get(key),
            "end": end,
            "growth_per_min_2nd_half": None if slope is None else round(slope, 1),
            "maxlen": cap,
            "where": w.where if w else "python-can virtual bus (can.interfaces.virtual.channels)",
        }
        try:
            entry = c[-1] if c else None
        except (IndexError, TypeError, KeyError):
            entry = None
        if entry is not None:
            info["bytes_per_entry"] = deep_size(entry)
            if slope is not None:
                info["kB_per_min_2nd_half"] = round(slope * info["bytes_per_entry"] / 1024, 1)
        before = info["middle"] or 0
        growing = slope is not None and slope > 5 and end > before + max(100, 0.1 * before)
        if w and w.time_bounded:
            info["verdict"] = f"time-bounded ({w.time_bounded})"
        elif cap and end >= cap:
            info["verdict"] = f"full at its maxlen {cap}"
        elif growing and cap:
            info["verdict"] = (
                f"growing, bounded: reaches its maxlen {cap} in ~{(cap - end) / slope:.1f} more "
                "min at this rate"
            )
        elif growing:
            info["verdict"] = "grows without bound"
        else:
            info["verdict"] = "flat"
        out[key] = info
    return out


def _second_half(series: list[dict[str, Any]], key: str, half_s: float) -> tuple[list, list]:
    pts = [(s["t_s"], s[key]) for s in series if s["t_s"] >= half_s and s.get(key) is not None]
    return [p[0] for p in pts], [p[1] for p in pts]


def _nearest(series: list[dict[str, Any]], t: float) -> dict[str, Any]:
    return min(series, key=lambda s: abs(s["t_s"] - t))


def run_soak(cfg: SoakConfig, log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Run the soak described by ``cfg``; return the summary (JSON-serialisable)."""
    say = log or (lambda _m: None)
    if cfg.trace and not tracemalloc.is_tracing():
        tracemalloc.start()
    old_switch = sys.getswitchinterval()
    if cfg.switch_interval_ms is not None:
        sys.setswitchinterval(cfg.switch_interval_ms / 1e3)
    t_proc0 = time.process_time()
    period_s = cfg.sync_period_ms / 1e3
    name = f"soak{uuid.uuid4().hex[:8]}"
    robot = MockRobot(left_hand(), seed=cfg.seed)
    device: MockNDITracker = register_robot(name, robot)
    can_cfg: CanBusConfig = default_can_config(
        channel=f"hexcal-{name}",
        sync_period_s=period_s,
        max_tpdo_delay_s=None if cfg.max_tpdo_delay_ms is None else cfg.max_tpdo_delay_ms / 1e3,
    )
    nodes = MockEncoderNodes(robot, can_cfg)
    # Count what the mock puts on the bus (the position TPDO of the six nodes), wrapping its _send: the
    # TPDOs sent while the driver's receive queue is on the channel (python-can's virtual bus
    # copies each frame into every queue on the channel), and those sent after it left (the
    # mock answering SYNCs it had not yet handled when the driver stopped: nobody to receive).
    tpdo_ids = {leg.tpdo_cob_id(can_cfg.tpdo) for leg in can_cfg.legs}
    mock_sent = {"tpdo": 0, "tpdo_while_driver_closing": 0, "tpdo_after_driver_closed": 0}
    mock_sent["other"] = 0
    # The channel's receive queues: the mock's, and the driver's from its start to its stop.
    channel_queues = can_virtual.channels.setdefault(can_cfg.channel, [])
    mock_q: list[Any] = []  # the mock's own receive queue, once it is open
    driver_q: list[Any] = []  # the driver's, once it is open
    seen_driver = [False]
    mock_send = nodes._send

    def listening() -> bool:
        """Is a receive queue other than the mock's on the channel (the driver's)?"""
        on = any(q is not mock_q[0] for q in channel_queues) if mock_q else False
        seen_driver[0] |= on
        return on

    def counting_send(msg: can.Message) -> None:
        before = listening()
        mock_send(msg)
        after = listening()
        if msg.arbitration_id not in tpdo_ids:
            mock_sent["other"] += 1
        elif before and after:
            mock_sent["tpdo"] += 1
        elif before:  # the driver closed its bus during this send: delivered or not
            mock_sent["tpdo_while_driver_closing"] += 1
        elif seen_driver[0]:
            mock_sent["tpdo_after_driver_closed"] += 1

    nodes._send = counting_send  # type: ignore[method-assign]
    nodes.start()
    mock_bus = nodes._bus  # to count the SYNCs it had not handled yet when it stopped
    mock_q.append(getattr(mock_bus, "queue", None))
    trk = NDITracker(f"ndimock://{name}", reset="command")
    enc = LegEncoders(can_cfg)
    tprobe = lprobe = None
    acq: Acquisition | None = None
    mover = Mover(robot, cfg)
    records: dict[str, Any] = {"attempts": 0, "recorded": 0, "refused": {}, "examples": {}}
    snap_mid = snap_end = None
    try:
        trk.connect()
        enc.start(timeout=2.0)

        def latched(index: int) -> tuple[int, np.ndarray] | str | None:
            """What the mock latched at the index-th SYNC (PENDING: not handled yet; None: no
            longer kept)."""
            with nodes._lock:  # syncs_seen and history change together under it
                if index >= nodes.syncs_seen:
                    return PENDING
                i = index - (nodes.syncs_seen - len(nodes.history))
                if not 0 <= i < len(nodes.history):
                    return None
                return nodes.history[i]

        tprobe, lprobe = TrackerProbe(trk), LegProbe(enc, latched)
        acq = Acquisition(tprobe, lprobe)
        driver_q.extend(q for q in channel_queues if q is not mock_q[0])

        watched = watch_list(robot, nodes, device, trk, enc, acq)

        def probe() -> dict[str, Any]:
            st = enc.status()
            tm = tracemalloc.get_traced_memory() if tracemalloc.is_tracing() else (None, None)
            lengths: dict[str, int | None] = {}
            for w in watched:
                c = w.get()
                lengths[w.label] = None if c is None else len(c)
            lengths["virtual bus rx queues (frames not yet received)"] = sum(
                q.qsize() for q in channel_queues
            )
            return {
                "t_s": round(time.monotonic() - t_wall0, 3),
                "rss_kB": rss_kb(),
                "tracemalloc_kB": None if tm[0] is None else round(tm[0] / 1024, 1),
                "cpu_s": round(time.process_time() - t_proc0, 3),
                "sync_sent": st["sync_sent"],
                "sets": st["sets"],
                "lengths": lengths,
            }

        t_wall0 = time.monotonic()
        thread_cpu0 = thread_cpu_s()
        sys_cpu0, proc_cpu0, load0 = system_cpu(), time.process_time(), loadavg()
        sampler = Sampler(cfg.sample_period_s, probe)
        acq.start()
        mover.start()
        sampler.take()
        sampler.start()
        say(
            f"soak {cfg.seconds:g} s, SYNC every {cfg.sync_period_ms:g} ms "
            f"(TPDO deadline {can_cfg.tpdo_deadline_s * 1e3:g} ms), tracker ndimock://{name}"
        )
        t_end = t_wall0 + cfg.seconds
        next_record = t_wall0 + cfg.record_period_s
        half_done = False
        while (now := time.monotonic()) < t_end:
            if cfg.attribute and not half_done and now >= t_wall0 + cfg.seconds / 2:
                half_done = True
                if tracemalloc.is_tracing():
                    snap_mid = tracemalloc.take_snapshot()
            if now >= next_record and now + cfg.settle_s + acq.window.duration_s < t_end:
                records["attempts"] += 1
                with mover.lock:  # the operator holds the robot still for the record
                    time.sleep(cfg.settle_s)
                    try:
                        acq.record()
                        records["recorded"] += 1
                    except PoseRefused as exc:
                        msg = str(exc)
                        kind = (
                            "device fault"
                            if "fault" in msg
                            else "moved (spread above the still-window limits)"
                            if "moved" in msg
                            else "incomplete sets"
                            if "incomplete" in msg
                            else "too few samples"
                        )
                        records["refused"][kind] = records["refused"].get(kind, 0) + 1
                        records["examples"].setdefault(kind, msg)
                next_record += cfg.record_period_s
                continue
            time.sleep(min(0.05, max(0.0, t_end - time.monotonic())))
        wall_s = time.monotonic() - t_wall0
        sampler.stop_evt.set()
        sampler.join()
        sampler.take()  # the last point, at the end of the run
        per_thread = {
            k: v - thread_cpu0.get(k, 0.0) for k, v in thread_cpu_s().items()
        }  # during the run (the main thread's imports and set-up excluded)
        cpu_s = time.process_time() - t_proc0
        sys_cpu1, proc_cpu1, load1 = system_cpu(), time.process_time(), loadavg()
        mover.stop_evt.set()
        mover.join()
        if cfg.attribute and tracemalloc.is_tracing():
            snap_end = tracemalloc.take_snapshot()
        acq.stop()
        enc.stop()
        # Frames the driver never handled: still in its virtual-bus receive queue at stop.
        unread = list(driver_q[0].queue) if driver_q else []
        unread_tpdo = sum(m.arbitration_id in tpdo_ids for m in unread)
        drained = lprobe.drain()
        st = enc.status()
    finally:
        mover.stop_evt.set()
        if acq is not None:
            acq.stop()
        enc.stop()
        nodes.stop()
        trk.close()
        unregister(name)
        sys.setswitchinterval(old_switch)
    rx = getattr(mock_bus, "queue", None)
    mock_syncs_unhandled = sum(
        m.arbitration_id == SYNC_COB_ID and not m.is_error_frame for m in (rx.queue if rx else ())
    )

    series = sampler.series
    half = cfg.seconds / 2
    rss_t, rss_y = _second_half(series, "rss_kB", half)
    tm_t, tm_y = _second_half(series, "tracemalloc_kB", half)
    rss_slope = linear_slope(rss_t, rss_y)
    tm_slope = linear_slope(tm_t, tm_y)
    mid = _nearest(series, half)
    last = series[-1]
    tm_growth_kb = (
        None
        if last["tracemalloc_kB"] is None or mid["tracemalloc_kB"] is None
        else round(last["tracemalloc_kB"] - mid["tracemalloc_kB"], 1)
    )
    mean_rss = float(np.mean(rss_y)) if rss_y else None
    rss_flat = (
        None
        if rss_slope is None or mean_rss is None
        else rss_slope < cfg.flat_rss_pct_per_min / 100 * mean_rss
    )
    tm_flat = None if tm_growth_kb is None else tm_growth_kb < cfg.flat_tracemalloc_mb * 1024
    flat = (
        None
        if rss_flat is None and tm_flat is None
        else bool(rss_flat is not False and tm_flat is not False)
    )

    # Containers: growth per minute over the second half, entry size, bound.
    containers = summarize_containers(series, watched, half, wall_s)
    mock_kb_min = sum(
        c.get("kB_per_min_2nd_half") or 0.0
        for c in containers.values()
        if c["where"].startswith("mock_hw/") and (c.get("kB_per_min_2nd_half") or 0.0) > 0
    )
    rss_unexplained = None if rss_slope is None else rss_slope - mock_kb_min
    flat_excl_mock = (
        None
        if rss_unexplained is None or mean_rss is None
        else rss_unexplained < cfg.flat_rss_pct_per_min / 100 * mean_rss
        and (
            tm_growth_kb is None
            or tm_growth_kb - mock_kb_min * (wall_s - half) / 60 < cfg.flat_tracemalloc_mb * 1024
        )
    )

    attribution = None
    if snap_mid is not None and snap_end is not None:
        filt = [tracemalloc.Filter(False, tracemalloc.__file__)]
        diff = snap_end.filter_traces(filt).compare_to(snap_mid.filter_traces(filt), "lineno")
        dt_min = max((wall_s - half) / 60.0, 1e-9)
        attribution = [
            {
                "where": f"{d.traceback[0].filename}:{d.traceback[0].lineno}",
                "kB_growth": round(d.size_diff / 1024, 1),
                "kB_per_min": round(d.size_diff / 1024 / dt_min, 1),
                "blocks_growth": d.count_diff,
            }
            for d in diff[:12]
            if d.size_diff > 0
        ]

    expected_syncs = wall_s / period_s
    legs = st["legs"]
    driver_frames = sum(leg["tpdo_frames"] for leg in legs)
    can_summary = {
        "sync_period_ms": cfg.sync_period_ms,
        "tpdo_deadline_ms": round(can_cfg.tpdo_deadline_s * 1e3, 3),
        "syncs_expected_at_period": round(expected_syncs),
        "sync_sent_driver": st["sync_sent"],
        "sync_seen_mock": nodes.syncs_seen,
        "sync_unhandled_by_mock_at_stop": mock_syncs_unhandled,
        "syncs_skipped_by_producer_stalls": lprobe.syncs_skipped_by_stalls,
        "tpdo_frames_sent_mock": mock_sent["tpdo"],
        "tpdo_frames_sent_mock_while_driver_closing": mock_sent["tpdo_while_driver_closing"],
        "tpdo_frames_sent_mock_after_driver_closed": mock_sent["tpdo_after_driver_closed"],
        "tpdo_frames_received_driver": driver_frames,
        "tpdo_frames_unread_at_stop": unread_tpdo,
        "tpdo_frames_lost": max(0, mock_sent["tpdo"] - driver_frames - unread_tpdo),
        "frames_per_s": round(driver_frames / wall_s, 1),
        "sets_driver": st["sets"],
        "sets_read": lprobe.sets,
        "sets_drained_after_stop": drained,
        "sets_complete": lprobe.complete,
        "sets_flagged": lprobe.flagged,
        "sets_with_missing_position": lprobe.with_missing,
        "sets_late_only": lprobe.late_only,
        "sets_late_and_two_positions_only": lprobe.late_twice_only,
        "sets_flagged_other": lprobe.other_flagged,
        "positions_checked_against_mock": lprobe.positions_checked,
        "wrong_positions_in_complete_sets": lprobe.wrong_in_complete,
        "wrong_positions_in_flagged_sets": lprobe.wrong_in_flagged,
        "wrong_positions_equal_to_previous_sync": lprobe.stale_by_one,
        "complete_sets_with_a_wrong_position": lprobe.wrong_complete_sets,
        "of_which_right_after_a_set_with_a_missing_position": (lprobe.wrong_complete_after_missing),
        "positions_in_sets_whose_sync_the_mock_had_not_handled": lprobe.wrong_before_latch,
        "sets_not_verifiable": lprobe.sets_unverifiable,
        "wrong_position_examples": lprobe.wrong_examples,
        "missing_positions_per_leg": lprobe.missing_positions,
        "duplicate_positions_per_leg": lprobe.duplicate_positions,
        "flagged_share": round(lprobe.flagged / max(lprobe.sets, 1), 6),
        "late_only_share": round(lprobe.late_only / max(lprobe.sets, 1), 6),
        "fault_counts": lprobe.fault_counts,
        "fault_examples": lprobe.fault_examples,
        "incomplete_sets_driver": st["incomplete_sets"],
        "missing_per_leg_driver": [leg["missing"] for leg in legs],
        "discarded_driver": st["discarded"],
        "error_frames": st["error_frames"],
        "bus_state": st["bus_state"],
        "index_first": lprobe.first_index,
        "index_last": lprobe.last_index,
        "index_gaps": lprobe.index_gaps,
        "index_gap_examples": lprobe.index_examples,
        "max_sync_interval_ms": round(lprobe.max_sync_interval_ms, 3),
        "min_sync_interval_ms": round(lprobe.min_sync_interval_ms, 3) if lprobe.sets > 1 else None,
        "tpdo_delay_after_sync_ms": lprobe.delay_percentiles_ms(),
        "mock_other_frames_sent": mock_sent["other"],
    }
    tracker_summary = tprobe.summary(wall_s, device.frame_rate_hz)
    checks = {
        "can_no_frame_lost (every TPDO the mock sent reached the driver)": (
            can_summary["tpdo_frames_lost"] == 0
            and driver_frames + unread_tpdo
            <= mock_sent["tpdo"] + mock_sent["tpdo_while_driver_closing"]
        ),
        "can_no_wrong_position_in_a_complete_set": lprobe.wrong_in_complete == 0,
        "can_index_never_skips": lprobe.index_gaps == 0
        and lprobe.first_index == 0
        and lprobe.last_index == st["sets"] - 1,
        "can_every_set_read (sets read == sets produced, none discarded)": (
            st["sets"] == lprobe.sets and st["discarded"] == 0
        ),
        "can_every_sync_reached_the_mock (seen, or still queued at stop)": (
            st["sync_sent"] == nodes.syncs_seen + mock_syncs_unhandled
        ),
        "tracker_no_frame_missed": tracker_summary["frames_missed"] == 0
        and tracker_summary["frames_backwards"] == 0,
        "tracker_no_crc_or_format_error": tracker_summary["crc_errors"] == 0
        and tracker_summary["format_errors"] == 0,
    }
    zero_dropped = all(checks.values())
    return {
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]) if sys.argv else "",
        "config": asdict(cfg),
        "machine": {
            "python": platform.python_version(),
            "cpus": os.cpu_count(),
            "platform": platform.platform(),
            "switch_interval_s": cfg.switch_interval_ms / 1e3
            if cfg.switch_interval_ms is not None
            else old_switch,
        },
        "machine_load_during_run": None
        if sys_cpu0 is None or sys_cpu1 is None
        else {
            "note": "other processes = machine busy time minus this process's CPU time "
            "(approximate: /proc/stat counts in ticks, and a VM's accounting is coarse)",
            "other_processes_cpu_s": round(
                sys_cpu1["busy_s"] - sys_cpu0["busy_s"] - (proc_cpu1 - proc_cpu0), 2
            ),
            "other_processes_cpu_over_wall": round(
                (sys_cpu1["busy_s"] - sys_cpu0["busy_s"] - (proc_cpu1 - proc_cpu0)) / wall_s, 3
            ),
            "steal_s": round(sys_cpu1["steal_s"] - sys_cpu0["steal_s"], 2),
            "loadavg_1min_start_end": [load0, load1],
        },
        "wall_s": round(wall_s, 3),
        "verdict": {
            "zero_dropped": zero_dropped,
            "checks": checks,
            "every_set_had_six_positions_in_time": lprobe.with_missing == 0,
            "memory_flat": flat,
            "timing_flagged_share": can_summary["flagged_share"],
            "late_only_share": can_summary["late_only_share"],
        },
        "can": can_summary,
        "tracker": tracker_summary,
        "acquisition": {
            "moves": mover.moves,
            "record_attempts": records["attempts"],
            "recorded": records["recorded"],
            "refused": records["refused"],
            "refusal_examples": records["examples"],
        },
        "memory": {
            "flat_definition": FLAT_DEFINITION.format(
                rss_pct=cfg.flat_rss_pct_per_min, tm_mb=cfg.flat_tracemalloc_mb
            ),
            "flat": flat,
            "rss_flat": rss_flat,
            "tracemalloc_flat": tm_flat,
            "rss_slope_kB_per_min_2nd_half": None if rss_slope is None else round(rss_slope, 1),
            "rss_mean_kB_2nd_half": None if mean_rss is None else round(mean_rss),
            "tracemalloc_slope_kB_per_min_2nd_half": None
            if tm_slope is None
            else round(tm_slope, 1),
            "tracemalloc_growth_kB_2nd_half": tm_growth_kb,
            "growth_explained_by_mock_containers_kB_per_min": round(mock_kb_min, 1),
            "rss_slope_minus_mock_containers_kB_per_min": None
            if rss_unexplained is None
            else round(rss_unexplained, 1),
            "flat_if_the_mock_containers_are_excluded (estimate)": flat_excl_mock,
            "containers": containers,
            "tracemalloc_attribution_2nd_half": attribution,
            "series": [{k: v for k, v in s.items() if k != "lengths"} for s in series],
        },
        "cpu": {
            "process_cpu_s": round(cpu_s, 3),
            "cpu_over_wall": round(cpu_s / wall_s, 3),
            "per_thread_cpu_s": {k: round(v, 2) for k, v in sorted(per_thread.items())},
        },
    }


def main(argv: list[str] | None = None) -> int:
    """Command line: run the soak, print the JSON summary (and write it with ``--json``)."""
    d = SoakConfig()
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=d.seconds)
    ap.add_argument("--sync-period-ms", type=float, default=d.sync_period_ms)
    ap.add_argument(
        "--max-tpdo-delay-ms",
        type=float,
        default=None,
        help="TPDO deadline after SYNC (default: half the SYNC period); must be < the period",
    )
    ap.add_argument("--move-period-s", type=float, default=d.move_period_s)
    ap.add_argument("--record-period-s", type=float, default=d.record_period_s)
    ap.add_argument("--sample-period-s", type=float, default=d.sample_period_s)
    ap.add_argument("--seed", type=int, default=d.seed)
    ap.add_argument("--no-tracemalloc", action="store_true", help="measure the RSS only")
    ap.add_argument(
        "--attribute",
        action="store_true",
        help="tracemalloc snapshot diff by source line, middle vs end (stalls threads briefly)",
    )
    ap.add_argument(
        "--switch-interval-ms",
        type=float,
        default=None,
        help="set the interpreter's GIL switch interval for the run (default: leave it, 5 ms)",
    )
    ap.add_argument("--json", type=Path, help="also write the summary here")
    ap.add_argument(
        "--check", action="store_true", help="exit 1 if a frame was dropped or memory grew"
    )
    a = ap.parse_args(argv)
    cfg = SoakConfig(
        seconds=a.seconds,
        sync_period_ms=a.sync_period_ms,
        max_tpdo_delay_ms=a.max_tpdo_delay_ms,
        move_period_s=a.move_period_s,
        record_period_s=a.record_period_s,
        sample_period_s=a.sample_period_s,
        seed=a.seed,
        trace=not a.no_tracemalloc,
        attribute=a.attribute,
        switch_interval_ms=a.switch_interval_ms,
    )
    summary = run_soak(cfg, log=lambda m: print(m, file=sys.stderr, flush=True))
    text = json.dumps(summary, indent=2)
    print(text)
    if a.json:
        a.json.write_text(text + "\n")
    if a.check and not (summary["verdict"]["zero_dropped"] and summary["verdict"]["memory_flat"]):
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
