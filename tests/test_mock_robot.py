"""The simulated robot behind every mock device: its public API, the pose history that lets a
tracker measure the pose as of a past instant, and the log of encoder latch instants."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats
from scipy.spatial.transform import Rotation

from hexcal.mock_hw.robot import MockRobot
from hexcal.sim.robots import left_hand
from hexcal.sim.simulate import NoiseModel


class FakeClock:
    def __init__(self) -> None:
        self.t = 50.0

    def __call__(self) -> float:
        return self.t


def _rot(deg: float) -> np.ndarray:
    return Rotation.from_euler("z", deg, degrees=True).as_matrix()


def test_public_api_unchanged():
    robot = MockRobot(left_hand(), seed=2)
    P, R = robot.true_pose()
    robot.move_to(P + [1.0, 0.0, 0.0], R)
    np.testing.assert_allclose(robot.true_pose()[0], P + [1.0, 0.0, 0.0])
    p, q, rms = robot.tracker_sample()
    assert p.shape == (3,) and q.shape == (4,) and rms > 0
    assert robot.encoder_readings().shape == (6,)
    robot.tool_visible = False
    assert robot.tracker_sample() is None and robot.tracker_sample(at=0.0) is None
    assert robot.truth is not None and robot.sim is not None


def test_pose_in_effect_at_a_past_instant():
    clock = FakeClock()
    robot = MockRobot(left_hand(), noise=NoiseModel(0.0, 0.0, 0.0), clock=clock)
    home_P, home_R = robot.true_pose()
    clock.t = 51.0
    robot.move_to(home_P + [0.0, 0.0, 10.0], _rot(1.0))
    clock.t = 52.0
    robot.move_to(home_P + [0.0, 0.0, 20.0], _rot(2.0))
    clock.t = 53.0
    for at, dz, deg in [
        (49.0, 0.0, 0.0),  # before the robot existed: its first pose
        (50.5, 0.0, 0.0),
        (51.0, 10.0, 1.0),  # a move is in effect from its own instant on
        (51.999, 10.0, 1.0),
        (52.5, 20.0, 2.0),
        (99.0, 20.0, 2.0),  # the future: the current pose
    ]:
        P, R = robot.pose_at(at)
        np.testing.assert_allclose(P, home_P + [0.0, 0.0, dz], err_msg=f"at {at}")
        expected_R = home_R if deg == 0.0 else _rot(deg)
        np.testing.assert_allclose(R, expected_R, atol=1e-12, err_msg=f"at {at}")
        p, q, _ = robot.tracker_sample(at=at)  # noise-free: the pose itself
        np.testing.assert_allclose(p, P, atol=1e-9)
        np.testing.assert_allclose(
            Rotation.from_quat(q, scalar_first=True).as_matrix(), R, atol=1e-9
        )
    np.testing.assert_allclose(robot.tracker_sample()[0], home_P + [0.0, 0.0, 20.0], atol=1e-9)


def test_encoder_latches_record_when_each_reading_was_taken():
    clock = FakeClock()
    robot = MockRobot(left_hand(), clock=clock, seed=4)
    clock.t = 50.25
    first = robot.encoder_readings()
    clock.t = 50.26
    second = robot.encoder_readings()
    (t1, r1), (t2, r2) = robot.encoder_latches
    assert (t1, t2) == (50.25, 50.26)
    assert r1 is first and r2 is second  # the very arrays returned: a device keeps them
    assert robot.encoder_latches.maxlen == MockRobot.ENCODER_LOG_LEN
    with pytest.raises(IndexError):
        robot.encoder_latches[2]


def _measure(robot: MockRobot, clock: FakeClock, encoders_first: bool, reads_now: bool):
    """Three moves; at each, four tracker and four encoder measurements (the devices' own
    instants), taken in one order or the other, with or without reads "now" in between."""
    P, R = robot.true_pose()
    trk, enc = [], []
    for k in range(3):
        clock.t += 1.0
        robot.move_to(P + [k + 1.0, 0.0, 0.0], R)
        ats = [clock.t + 0.01 * n for n in range(4)]
        order = ["enc"] * 4 + ["trk"] * 4 if encoders_first else ["trk", "enc"] * 4
        it = {"trk": iter(ats), "enc": iter(ats)}
        for kind in order:
            if reads_now:
                robot.encoder_readings()
                robot.tracker_sample()
            if kind == "trk":
                trk.append(robot.tracker_sample(at=next(it["trk"]))[0])
            else:
                enc.append(robot.encoder_readings(at=next(it["enc"])))
    return np.array(trk), np.array(enc)


def test_a_measurement_is_the_same_whatever_else_was_measured_meanwhile():
    """The n-th measurement of a pose by an instrument depends on the seed, the pose and n
    only: not on the order the devices' threads asked in, nor on reads "now" in between."""
    runs = []
    for encoders_first, reads_now in [(False, False), (True, True)]:
        clock = FakeClock()
        robot = MockRobot(left_hand(), seed=9, clock=clock)
        runs.append(_measure(robot, clock, encoders_first, reads_now))
    (trk_a, enc_a), (trk_b, enc_b) = runs
    np.testing.assert_array_equal(trk_a, trk_b)
    np.testing.assert_array_equal(enc_a, enc_b)
    clock = FakeClock()
    trk_c, enc_c = _measure(MockRobot(left_hand(), seed=10, clock=clock), clock, False, False)
    assert not np.any(trk_c == trk_a) and not np.any(enc_c == enc_a)  # another seed


def test_the_keyed_noise_has_the_stated_sigma_and_no_memory():
    """Drawn per measurement from its own stream, the noise is still white with the stated σ:
    800 readings of one pose (χ² bounds on the variance at 1e-4, lag-one correlation within 4σ)."""
    clock = FakeClock()
    robot = MockRobot(left_hand(), noise=NoiseModel(0.01, 0.002, 0.002), clock=clock, seed=3)
    truth = robot.sim.readings(*[x[None] for x in robot.true_pose()])[0]
    r = np.array([robot.encoder_readings(at=50.0 + 1e-3 * n) for n in range(800)]) - truth
    n = r.size
    lo, hi = stats.chi2.ppf([1e-4, 1 - 1e-4], n) / n
    assert lo < np.var(r) / 0.002**2 < hi
    lag = np.corrcoef(r[:-1].ravel(), r[1:].ravel())[0, 1]
    assert abs(lag) < 4 / np.sqrt(n)
