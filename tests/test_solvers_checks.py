"""Degenerate or too-small pose sets are refused with a message that names the motion to add."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_solvers_paper import K

from hexcal.estimate.solvers.checks import (
    DegenerateSet,
    check_type_i,
    check_type_ii,
    check_type_iii,
)


def _about_one_axis(sim, n, rng, axis=(0.0, 0.0, 1.0)):
    """Type II poses whose rotations all share one axis."""
    u, length = sim.home_leg(K)
    c = sim.robot.a[K] + length * u
    angles = np.deg2rad(rng.uniform(-10, 10, n))
    R = Rotation.from_rotvec(np.outer(angles, axis)).as_matrix()
    return c - R @ sim.robot.b[K], R


def test_type_ii_single_axis_refused(clean_sim, rng):
    P, R = _about_one_axis(clean_sim, 8, rng)
    with pytest.raises(DegenerateSet, match=r"one axis.*second, perpendicular axis"):
        check_type_ii(3, P, R)


def test_type_ii_good_set_accepted(clean_sim, rng):
    check_type_ii(3, *clean_sim.type_ii(K, (8,), rng))


def test_type_i_equal_lengths_refused(clean_sim, rng):
    P, R = clean_sim.type_i(K, (8,), rng)
    u, length = clean_sim.home_leg(K)
    # Rebuild the set with the clamped length held constant.
    P = clean_sim.robot.a[K] + length * u - R @ clean_sim.robot.b[K]
    with pytest.raises(DegenerateSet, match=r"length hardly changed.*extend and retract leg 3"):
        check_type_i(3, P, R, np.full(8, length))


def test_type_i_no_rotation_refused(clean_sim, rng):
    u, _ = clean_sim.home_leg(K)
    lengths = np.linspace(190, 230, 8)
    R = np.broadcast_to(np.eye(3), (8, 3, 3))
    P = clean_sim.robot.a[K] + lengths[:, None] * u - R @ clean_sim.robot.b[K]
    with pytest.raises(DegenerateSet, match=r"hardly rotated.*two different axes"):
        check_type_i(3, P, R, lengths)


def test_too_few_poses_refused(clean_sim, rng):
    P, R = clean_sim.type_iii(K, (3,), rng)
    with pytest.raises(DegenerateSet, match=r"3 recorded, at least 4 needed"):
        check_type_iii(3, P, R, clean_sim.robot.b[K])


def test_type_iii_one_direction_refused(clean_sim, rng):
    u0, length = clean_sim.home_leg(K)
    side = np.cross(u0, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    angles = np.deg2rad(np.linspace(-10, 10, 8))
    u = Rotation.from_rotvec(np.outer(angles, side)).apply(u0)
    R = np.broadcast_to(np.eye(3), (8, 3, 3))
    P = clean_sim.robot.a[K] + length * u - R @ clean_sim.robot.b[K]
    with pytest.raises(DegenerateSet, match=r"one direction only.*sideways"):
        check_type_iii(3, P, R, clean_sim.robot.b[K])
