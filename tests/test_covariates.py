"""The explorer's covariates of a change's direction (hexcal.effects.covariates): whether a
leg's axial load last rose or fell, and whether the structure was last warming or cooling —
checked against the sign of the last change computed here by hand."""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.effects.base import EffectData
from hexcal.effects.compliance import leg_forces
from hexcal.effects.covariates import TEMPERATURE_JITTER_K, covariate_values
from hexcal.model.robot import Robot
from hexcal.sim.robots import left_hand


def _data(n: int, temperature: np.ndarray | None = None) -> EffectData:
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
    data = _data(40)
    f = leg_forces(data, 20.0)
    step = np.diff(f, axis=0)
    assert np.all(np.abs(step) > 1e-3 * np.ptp(f, axis=0)), "every pose changes every load"
    got = covariate_values("force_change", data)
    np.testing.assert_array_equal(got[0], 0.0)  # no change before the first pose
    np.testing.assert_array_equal(got[1:], np.sign(step))


def test_temperature_change_says_warming_or_cooling_and_keeps_it_through_jitter():
    jitter = 0.5 * TEMPERATURE_JITTER_K
    temp = np.array([20.0, 20.5, 21.0, 20.9, 20.9 + jitter, 20.5, 20.5 - jitter, 20.8])
    data = dataclasses.replace(_data(len(temp)), temperature=temp)
    got = covariate_values("temperature_change", data)
    want = np.array([0, 1, 1, -1, -1, -1, -1, 1], float)
    np.testing.assert_array_equal(got, np.repeat(want[:, None], 6, axis=1))
