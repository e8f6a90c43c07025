"""The covariates effects are fitted along (hexcal.effects.covariates), against what they are
by hand: a leg's inclination and azimuth from its vector, the time since a procedure step
began, a lab's numeric columns, and which of them are one value per pose."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hexcal.effects.base import EffectData
from hexcal.effects.covariates import covariate_values, lagged_covariate, library, numeric_columns
from hexcal.sim.robots import left_hand
from hexcal.sim.simulate import PoseRanges, Simulator

ROBOT = left_hand()


def _data(n: int = 7, t=None, step=None) -> EffectData:
    sim = Simulator(ROBOT, ranges=PoseRanges(box_mm=(40.0, 40.0, 30.0), tilt_deg=15.0))
    P, R = sim.free((n,), np.random.default_rng(12))
    t = np.arange(n, dtype=float) if t is None else np.asarray(t, float)
    return EffectData(np.zeros((n, 6)), P, R, t, None, ROBOT, ROBOT.a, ROBOT.b, step=step)


def test_inclination_and_azimuth_are_each_legs_angles_by_hand():
    """Each leg's vector p + R b_k − a_k: its angle from the vertical, and its azimuth about the
    vertical less the leg's azimuth at the home pose, wrapped to ±180°."""
    d = _data()
    v = d.position[:, None] + np.einsum("mij,kj->mki", d.rotation, ROBOT.b) - ROBOT.a
    incl = np.degrees(np.arccos(v[..., 2] / np.linalg.norm(v, axis=-1)))
    assert covariate_values("inclination", d) == pytest.approx(incl, abs=1e-9)
    q = np.asarray(ROBOT.home.quaternion, float)  # scalar first
    home = Rotation.from_quat([q[1], q[2], q[3], q[0]])
    hv = np.asarray(ROBOT.home.position, float) + home.apply(ROBOT.b) - ROBOT.a
    az = np.degrees(np.arctan2(v[..., 1], v[..., 0]) - np.arctan2(hv[:, 1], hv[:, 0]))
    az = (az + 180.0) % 360.0 - 180.0
    got = covariate_values("azimuth", d)
    assert got == pytest.approx(az, abs=1e-9)
    assert np.ptp(got) > 1.0 and np.ptp(covariate_values("inclination", d)) > 1.0


def test_step_time_restarts_with_each_step_and_runs_on_without_steps():
    """Steps a, a, b, b, b, a (a step begins anew wherever it changes): the time since each
    one began; poses from no procedure: the time since the first pose."""
    t = [10.0, 12.5, 20.0, 21.0, 23.5, 30.0]
    d = _data(6, t=t, step=np.array(["a", "a", "b", "b", "b", "a"], dtype=object))
    assert covariate_values("step_time", d)[:, 0] == pytest.approx([0, 2.5, 0, 1, 3.5, 0])
    d = _data(6, t=t)
    assert covariate_values("step_time", d)[:, 0] == pytest.approx([0, 2.5, 10, 11, 13.5, 20])


def test_numeric_columns_are_kept_whatever_comes_before_them():
    """A text column (an operator's initials) before a lab's thermometer and a constant one:
    the thermometer is kept, the text and the constant are not."""
    extra = {
        "operator": np.array(["jd", "jd", "mk"]),
        "bench_C": np.array(["20.1", "20.4", "20.9"]),
        "build": np.array(["7", "7", "7"]),
    }
    got = numeric_columns(extra)
    assert list(got) == ["bench_C"] and got["bench_C"] == pytest.approx([20.1, 20.4, 20.9])


def test_a_covariate_is_per_pose_exactly_when_its_six_legs_values_are_one():
    """Every covariate of the library (a session with a temperature) and a lagged temperature:
    flagged per pose — the explorer then tests it once, against the pose's mean residual —
    exactly when its values are the same for the six legs at every pose."""
    d = dataclasses.replace(
        _data(7),
        temperature=np.linspace(20.0, 22.0, 7),
        readings=np.random.default_rng(0).normal(50.0, 5.0, (7, 6)),
    )
    covs = [*library(d), lagged_covariate("temperature", 60.0)]
    assert len(covs) > 20
    for c in covs:
        v = np.asarray(c.values(d), float)
        assert c.per_pose == bool(np.all(v == v[:, [0]])), c.name


def test_tilt_is_the_platforms_turn_away_from_its_normal_at_home():
    """Rotations from home about horizontal axes by 0°, 5° and 12°, each after a yaw of 30°
    (a turn about the normal, no tilt): the tilt is 0°, 5° and 12°."""
    d0 = _data(3)
    yaw = Rotation.from_euler("z", 30.0, degrees=True)
    turns = [
        Rotation.from_rotvec(np.deg2rad(a) * np.array([np.cos(c), np.sin(c), 0.0]))
        for a, c in ((0.0, 0.3), (5.0, 1.1), (12.0, 2.5))
    ]
    R = np.stack([(t * yaw).as_matrix() for t in turns])
    d = dataclasses.replace(d0, rotation=R)
    assert covariate_values("tilt", d)[:, 0] == pytest.approx([0.0, 5.0, 12.0], abs=1e-6)
