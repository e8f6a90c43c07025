"""Acquisition: a still window becomes a recorded pose; motion, faults, missing data refuse it."""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hexcal.acquire.acquisition import (
    Acquisition,
    LegSample,
    PoseRefused,
    StillWindow,
    TrackerSample,
    record_pose,
)
from hexcal.mock_hw.robot import MockRobot
from hexcal.sim.robots import left_hand

WINDOW = StillWindow(duration_s=0.5)
TOLERANT = StillWindow(duration_s=0.5, max_fault_share=0.1)


def _samples(n=20, move_mm=0.0, leg_move=0.0, t0=0.0, rng=None, sigma_mm=0.002):
    rng = rng or np.random.default_rng(0)
    q = Rotation.from_rotvec([0.01, -0.02, 0.03]).as_quat(scalar_first=True)
    ts = [
        TrackerSample(
            t0 + 0.5 * i / n,
            np.array([1.0, 2.0, 200.0 + move_mm * i / n]) + rng.normal(0, sigma_mm, 3),
            q,
            0.01,
        )
        for i in range(n)
    ]
    ls = [
        LegSample(
            t0 + 0.5 * i / n + 0.001,
            np.full(6, 60.0) + leg_move * i / n * (np.arange(6) == 2) + rng.normal(0, 0.001, 6),
        )
        for i in range(n)
    ]
    return ts, ls


def test_still_window_is_averaged_and_raw_samples_kept():
    ts, ls = _samples()
    pose = record_pose(ts, ls, WINDOW, t_end=0.5)
    assert np.allclose(pose.position, [1, 2, 200], atol=0.002)
    assert np.allclose(pose.readings, 60.0, atol=0.001)
    assert len(pose.tracker_samples) == 20 and len(pose.leg_samples) == 20
    assert abs(pose.alignment_s) < 0.002


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"move_mm": 1.0}, "platform moved during the pose"),
        ({"leg_move": 0.5}, "leg 3 moved during the pose"),
    ],
)
def test_motion_refuses_the_pose(kwargs, match):
    ts, ls = _samples(**kwargs)
    with pytest.raises(PoseRefused, match=match):
        record_pose(ts, ls, WINDOW, t_end=0.5)


def test_a_noisy_still_pose_is_kept_and_a_slow_drift_of_the_same_size_is_not():
    """Motion is judged by drift between the window's halves, not by max − min: a tracker whose
    noise (σ 0.02 mm) spreads the samples over more than the 0.05 mm limit is still; a drift of
    that same 0.06 mm over the window is motion."""
    ts, ls = _samples(sigma_mm=0.02, rng=np.random.default_rng(3))
    pose = record_pose(ts, ls, WINDOW, t_end=0.5)
    assert pose.position_spread_mm > WINDOW.max_position_drift_mm  # the old test would refuse
    ts, ls = _samples(move_mm=0.12, rng=np.random.default_rng(3))
    with pytest.raises(PoseRefused, match=r"platform moved during the pose \(drifted 0\.0"):
        record_pose(ts, ls, WINDOW, t_end=0.5)


def test_one_flagged_sample_refuses_the_pose_by_default():
    """A pose taken during a fault is refused, never kept: one CRC error in 20 samples is
    enough, and the message names it."""
    ts, ls = _samples()
    ts[7] = TrackerSample(ts[7].t, None, None, fault="CRC error in the reply to BX")
    with pytest.raises(PoseRefused, match=r"1 of 20 tracker samples flagged\): CRC error"):
        record_pose(ts, ls, WINDOW, t_end=0.5)


def test_the_lasting_cause_is_named_before_its_glitches():
    """A node falls silent: its first sets lack its position (before the heartbeat timeout),
    then every set names it silent, each with its own age. The silent message, which spoiled
    most sets, comes first, told once, by its latest instance."""
    ts, ls = _samples()
    for i in range(6, 8):
        ls[i] = LegSample(ls[i].t, np.full(6, np.nan), (f"leg 3 sent no position for SYNC {i}",))
    for i in range(8, 14):
        age = f"{0.1 * (i - 3):.1f}"
        ls[i] = LegSample(
            ls[i].t, np.full(6, np.nan), (f"leg 3 encoder silent for {age} s: no heartbeat",)
        )
    with pytest.raises(PoseRefused) as err:
        record_pose(ts, ls, WINDOW, t_end=0.5)
    text = str(err.value)
    assert "8 of 20 leg reading sets flagged): leg 3 encoder silent for 1.0 s" in text
    assert text.count("silent") == 1 and text.index("silent") < text.index("SYNC 7")


def test_a_lasting_fault_refuses_the_pose_even_where_glitches_are_allowed():
    ts, ls = _samples()
    for i in (3, 7, 11):  # 3 of 20 flagged: more than max_fault_share (10 %)
        ts[i] = TrackerSample(
            ts[i].t, None, None, fault="tool 01 MISSING (out of the tracker's view)"
        )
    with pytest.raises(PoseRefused, match=r"3 of 20 tracker samples flagged\): tool 01 MISSING"):
        record_pose(ts, ls, TOLERANT, t_end=0.5)
    ts, ls = _samples()
    for i in (3, 4, 5):
        ls[i] = LegSample(ls[i].t, np.r_[np.full(5, 60.0), np.nan], ("leg 6 sent no position",))
    with pytest.raises(PoseRefused, match=r"3 of 20 leg reading sets flagged\): leg 6 sent no"):
        record_pose(ts, ls, TOLERANT, t_end=0.5)


def test_where_glitches_are_allowed_one_is_left_out_and_noted():
    """With ``max_fault_share`` 10 % (a lab's choice), one flagged sample of 20 (a late CAN
    set, a frame with a CRC error) is left out of the average, named in the notes, and kept
    with the raw samples."""
    ts, ls = _samples()
    ts[7] = TrackerSample(ts[7].t, None, None, fault="CRC error in the reply to BX")
    ls[3] = LegSample(ls[3].t, np.r_[np.full(5, 60.0), 999.0], ("leg 6 arrived 7 ms after SYNC",))
    pose = record_pose(ts, ls, TOLERANT, t_end=0.5)
    assert np.allclose(pose.readings, 60.0, atol=0.001)  # the flagged 999 is not averaged in
    assert len(pose.tracker_samples) == 20 and len(pose.good_tracker_samples) == 19
    assert len(pose.leg_samples) == 20 and len(pose.good_leg_samples) == 19
    assert any("CRC error" in n for n in pose.notes) and any(
        "7 ms after SYNC" in n for n in pose.notes
    )


@pytest.mark.parametrize("uncertainty_s, kept", [(0.0, False), (0.004, True)])
def test_a_sample_that_may_predate_the_window_is_not_in_it(uncertainty_s, kept):
    """A frame measured just before the window began (the platform still on its way from the
    last pose) stamped 2 ms into it: stamped exactly, it is in the window and the pose is
    refused as moving; with its 4 ms timing uncertainty it may predate the window, and is
    left out."""
    ts, ls = _samples()
    before = TrackerSample(
        0.002, ts[0].position + [3.0, 0.0, 0.0], ts[0].quaternion, 0.01, None, uncertainty_s
    )
    samples = [before, *ts[1:]]
    if kept:
        pose = record_pose(samples, ls, WINDOW, t_end=0.5)
        assert before not in pose.tracker_samples
        assert np.allclose(pose.position, [1.0, 2.0, 200.0], atol=0.01)
    else:
        with pytest.raises(PoseRefused, match="moved"):
            record_pose(samples, ls, WINDOW, t_end=0.5)


def test_too_few_samples():
    ts, ls = _samples(n=3)
    with pytest.raises(PoseRefused, match=r"tracker gave 3 good samples"):
        record_pose(ts, ls, WINDOW, t_end=0.5)


class _Tracker:
    def __init__(self, robot, hz=200.0):
        self.robot, self.dt = robot, 1.0 / hz

    def sample(self):
        time.sleep(self.dt)
        s = self.robot.tracker_sample()
        if s is None:
            return TrackerSample(time.monotonic(), None, None, fault="tool MISSING")
        return TrackerSample(time.monotonic(), s[0], s[1], s[2])


class _Legs:
    def __init__(self, robot, hz=200.0):
        self.robot, self.dt = robot, 1.0 / hz

    def sample(self):
        time.sleep(self.dt)
        return LegSample(time.monotonic(), self.robot.encoder_readings())


def test_threaded_acquisition_against_the_mock_robot():
    robot = MockRobot(left_hand(), seed=1)
    window = StillWindow(duration_s=0.2)  # default motion limits against the mock's noise
    with Acquisition(_Tracker(robot), _Legs(robot), window) as acq:
        time.sleep(0.05)
        pose = acq.record()
        P, R = robot.true_pose()
        assert np.allclose(pose.position, P, atol=0.02)
        truth = robot.sim.readings(P[None], R[None])[0]
        assert np.allclose(pose.readings, truth, atol=0.005)
        robot.tool_visible = False
        with pytest.raises(PoseRefused, match="MISSING"):
            acq.record()


class _StallingTracker(_Tracker):
    """A tracker read by a thread the computer holds back now and then: ``stall_next`` s before
    the next sample (the device itself is fine)."""

    stall_next = 0.0

    def sample(self):
        stall, self.stall_next = self.stall_next, 0.0
        time.sleep(stall)
        return super().sample()


def test_a_window_a_busy_computer_left_short_is_taken_again_and_said(caplog):
    """The tracker's thread is held back for most of the window: the window came short with
    nothing wrong with the device, so it is taken again (the platform still stands), logged
    and noted in the pose — not refused as a tracking fault."""
    robot = MockRobot(left_hand(), seed=1)
    tracker = _StallingTracker(robot, hz=100.0)
    with Acquisition(tracker, _Legs(robot), StillWindow(duration_s=0.2)) as acq:
        time.sleep(0.05)
        tracker.stall_next = 0.17
        with caplog.at_level("INFO", logger="hexcal.acquire.acquisition"):
            pose = acq.record()
    assert any("taken 2 times" in n and "good samples" in n for n in pose.notes), pose.notes
    assert any("taking the window again" in r.getMessage() for r in caplog.records)
    assert len(pose.good_tracker_samples) >= 5


def test_a_stream_short_window_after_window_is_refused_saying_so():
    """A tracker that never gives enough samples in a window (15 Hz against 5 in 0.2 s) is
    refused after the retakes, saying how many windows came short."""
    robot = MockRobot(left_hand(), seed=1)
    with Acquisition(_Tracker(robot, hz=15.0), _Legs(robot), StillWindow(duration_s=0.2)) as acq:
        time.sleep(0.05)
        with pytest.raises(PoseRefused, match=r"good samples .*3 windows in a row came short"):
            acq.record()


# -- numbers no pose can have (defence in depth behind the drivers) --------------------------------
@pytest.mark.parametrize(
    "position, quaternion, said",
    [
        ([np.nan, 2.0, 200.0], None, r"non-finite position \[ *nan"),
        ([1.0, 2.0, np.inf], None, r"non-finite position"),
        (None, [1.0, np.nan, 0.0, 0.0], r"non-finite quaternion"),
        (None, [0.0, 0.0, 0.0, 0.0], r"quaternion of norm 0, not a rotation"),
        ([1.0, 2.0], None, r"malformed position \(not 3 numbers\)"),
    ],
)
def test_a_sample_with_numbers_no_pose_can_have_is_a_fault(position, quaternion, said):
    """NaN compares false: unchecked, it passes every drift check. A tracker sample whose pose
    is not finite (or not a pose at all) is a fault of that sample even when the device did not
    say so; the pose is refused by default, and where glitches are allowed it is left out and
    its raw copy carries no pose, so the session file can hold it."""
    ts, ls = _samples()
    good = ts[7]
    ts[7] = TrackerSample(
        good.t,
        good.position if position is None else np.array(position),
        good.quaternion if quaternion is None else np.array(quaternion),
        0.01,
    )
    with pytest.raises(
        PoseRefused,
        match=rf"1 of 20 tracker samples flagged\): tracker sample "
        rf"at t = 0\.175 s: {said}",
    ):
        record_pose(ts, ls, WINDOW, t_end=0.5)
    pose = record_pose(ts, ls, TOLERANT, t_end=0.5)
    assert len(pose.good_tracker_samples) == 19 and any(
        "non" in n or "not" in n for n in pose.notes
    )
    raw = pose.tracker_samples[7]
    assert raw.position is None and raw.quaternion is None and raw.fault
    for s in pose.tracker_samples:
        assert s.position is None or np.all(np.isfinite(s.position))
    assert np.all(np.isfinite(pose.position)) and np.all(np.isfinite(pose.quaternion))


def test_a_reading_set_with_a_non_finite_reading_is_named():
    ts, ls = _samples()
    ls[4] = LegSample(ls[4].t, np.r_[np.full(2, 60.0), np.inf, np.full(3, 60.0)])
    with pytest.raises(
        PoseRefused,
        match=r"1 of 20 leg reading sets flagged\): leg reading set at t = 0\.101 s: no finite "
        r"reading from leg 3",
    ):
        record_pose(ts, ls, WINDOW, t_end=0.5)


def test_a_window_whose_average_is_not_finite_is_refused():
    """Finite samples can still average to infinity (1e308 + 1e308 overflows): the last guard
    refuses the window rather than record an inf the session cannot hold."""
    ts, ls = _samples(sigma_mm=0.0)
    ts = [TrackerSample(s.t, np.array([1e308, 2.0, 200.0]), s.quaternion, 0.01) for s in ts]
    with pytest.raises(PoseRefused, match=r"averaged position is not a finite number"):
        record_pose(ts, ls, WINDOW, t_end=0.5)


# -- windows a motion controller anchors (the mock rig's reproducible sessions) ---------------------
class _Clocked:
    """A source giving samples stamped on a fixed grid (period s, first at ``t0``), each the
    next of ``values``: what a device measures at its own instants, whatever the host does."""

    def __init__(self, make, period: float, t0: float):
        self.make, self.period, self.n, self.t0 = make, period, 0, t0

    def sample(self):
        t = self.t0 + self.n * self.period
        time.sleep(max(0.0, t - time.monotonic()))
        self.n += 1
        return self.make(t, self.n)


def _grid_acquisition(window: StillWindow) -> Acquisition:
    q = np.array([1.0, 0.0, 0.0, 0.0])
    t0 = time.monotonic()
    tracker = _Clocked(
        lambda t, n: TrackerSample(t, np.array([0.0, 0.0, n * 1e-4]), q, 0.01), 0.01, t0
    )
    legs = _Clocked(lambda t, n: LegSample(t, np.full(6, 50.0 + n * 1e-5)), 0.004, t0 + 0.001)
    return Acquisition(tracker, legs, window)


def test_an_anchored_window_starts_where_the_platform_came_to_rest_not_at_the_request():
    """Told when the platform came to rest, the window is the samples from there on, even when
    record() is called later; the next window at that pose goes on from the first's end."""
    with _grid_acquisition(StillWindow(duration_s=0.1, max_position_drift_mm=1.0)) as acq:
        time.sleep(0.05)
        rest = time.monotonic() + 0.0055
        acq.anchor(rest)
        time.sleep(0.3)  # the operator takes a while to press the key
        first = acq.record()
        second = acq.record()
    t_first = [s.t for s in first.tracker_samples]
    assert rest <= t_first[0] < rest + 0.01 and t_first[-1] <= rest + 0.1
    assert min(s.t for s in first.leg_samples) >= rest
    assert max(s.t for s in first.leg_samples) <= rest + 0.1
    # Contiguous: the second window starts where the first ended.
    assert t_first[-1] < second.tracker_samples[0].t <= t_first[-1] + 0.0101
    assert max(s.t for s in first.leg_samples) < min(s.t for s in second.leg_samples)


def test_a_counted_window_holds_exactly_its_samples_and_goes_on_from_them():
    """tracker_samples / leg_samples: the first so many of each stream from the window's start,
    and the next window the next so many — the same samples however the host was timed."""
    window = StillWindow(
        duration_s=0.1, max_position_drift_mm=1.0, tracker_samples=7, leg_samples=20
    )
    with _grid_acquisition(window) as acq:
        time.sleep(0.05)
        rest = time.monotonic() + 0.0055
        acq.anchor(rest)
        first, second = acq.record(), acq.record()
    assert (len(first.tracker_samples), len(first.leg_samples)) == (7, 20)
    assert (len(second.tracker_samples), len(second.leg_samples)) == (7, 20)
    n_trk = [round(s.position[2] / 1e-4) for s in first.tracker_samples + second.tracker_samples]
    assert n_trk == list(range(n_trk[0], n_trk[0] + 14))  # consecutive: none skipped or repeated
    n_leg = [round((s.readings[0] - 50.0) / 1e-5) for s in first.leg_samples + second.leg_samples]
    assert n_leg == list(range(n_leg[0], n_leg[0] + 40))
    assert first.tracker_samples[0].t >= rest > first.tracker_samples[0].t - 0.01


def test_a_counted_window_whose_stream_stops_is_short():
    window = StillWindow(duration_s=0.05, tracker_samples=500, leg_samples=5)
    with _grid_acquisition(window) as acq:
        time.sleep(0.02)
        with pytest.raises(PoseRefused, match=r"the tracker gave \d+ of 500 samples in time"):
            acq.record()


def test_without_an_anchor_a_window_starts_at_the_request():
    with _grid_acquisition(StillWindow(duration_s=0.1, max_position_drift_mm=1.0)) as acq:
        time.sleep(0.05)
        asked = time.monotonic()
        pose = acq.record()
    assert pose.tracker_samples[0].t >= asked
