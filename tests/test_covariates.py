"""The covariates effects are fitted along (hexcal.effects.covariates), against what they are
by hand: a leg's inclination and azimuth from its vector, the time since a procedure step
began, a lab's numeric columns, which of them are one value per pose, and the direction of a
change (whether a leg's load last rose or fell, whether the structure was warming)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hexcal.effects.base import EffectData
from hexcal.effects.compliance import leg_forces
from hexcal.effects.covariates import (
    TEMPERATURE_JITTER_K,
    covariate_values,
    lagged_covariate,
    library,
    numeric_columns,
)
from hexcal.model.robot import Robot
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


def _moving(n: int, temperature: np.ndarray | None = None) -> EffectData:
    """n poses of the Left Hand about home: the platform moving along z and tilting, so that
    every leg's load changes from pose to pose."""
    robot: Robot = left_hand().model_copy(update={"platform_mass_kg": 20.0})
    home = np.asarray(robot.home.position, float)
    rng = np.random.default_rng(7)
    pos = home + np.column_stack([rng.uniform(-20, 20, (n, 2)), rng.uniform(-15, 15, n)])
    rot = Rotation.from_rotvec(np.deg2rad(rng.uniform(-8, 8, (n, 3)))).as_matrix()
    lengths = np.linalg.norm(
        pos[:, None, :] + np.einsum("nij,kj->nki", rot, robot.b) - robot.a[None], axis=-1
    )
    temp = np.full(n, 20.0) if temperature is None else temperature
    return EffectData(
        lengths - np.asarray(robot.offsets), pos, rot, np.arange(n, dtype=float), temp, robot,
        robot.a, robot.b,
    )  # fmt: skip


def test_force_change_is_the_sign_of_each_legs_last_load_change():
    data = _moving(40)
    f = leg_forces(data, 20.0)
    step = np.diff(f, axis=0)
    assert np.all(np.abs(step) > 1e-3 * np.ptp(f, axis=0)), "every pose changes every load"
    got = covariate_values("force_change", data)
    np.testing.assert_array_equal(got[0], 0.0)  # no change before the first pose
    np.testing.assert_array_equal(got[1:], np.sign(step))


def test_temperature_change_says_warming_or_cooling_and_keeps_it_through_jitter():
    jitter = 0.5 * TEMPERATURE_JITTER_K
    temp = np.array([20.0, 20.5, 21.0, 20.9, 20.9 + jitter, 20.5, 20.5 - jitter, 20.8])
    data = dataclasses.replace(_moving(len(temp)), temperature=temp)
    got = covariate_values("temperature_change", data)
    want = np.array([0, 1, 1, -1, -1, -1, -1, 1], float)
    np.testing.assert_array_equal(got, np.repeat(want[:, None], 6, axis=1))
