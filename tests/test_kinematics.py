"""Inverse and forward kinematics and the platform Jacobian."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hexcal.model.kinematics import (
    ForwardKinematicsError,
    condition_number,
    forward_kinematics,
    inverse_kinematics,
    leg_vectors,
    platform_jacobian,
)


def test_ik_vectorised_matches_loop(design, rng):
    P = rng.normal(0, 10, (5, 3)) + np.array([0.0, 0.0, 200.0])
    R = Rotation.from_rotvec(rng.normal(0, 0.1, (5, 3)))
    L = inverse_kinematics(design.a, design.b, P, R)
    for i in range(5):
        for k in range(6):
            assert L[i, k] == pytest.approx(
                np.linalg.norm(P[i] + R[i].apply(design.b[k]) - design.a[k]), rel=1e-14
            )


@pytest.mark.parametrize("seed", range(5))
def test_fk_inverts_ik(design, seed):
    rng = np.random.default_rng(seed)
    P = rng.uniform(-15, 15, 3) + np.array([0.0, 0.0, 200.0])
    R = Rotation.from_rotvec(rng.uniform(-0.2, 0.2, 3))
    L = inverse_kinematics(design.a, design.b, P[None], R)[0]
    p, r = forward_kinematics(design.a, design.b, L)
    assert np.allclose(p, P, atol=1e-8)
    assert (r * R.inv()).magnitude() < 1e-10


def test_fk_refuses_impossible_lengths(design):
    with pytest.raises(ForwardKinematicsError, match="did not close"):
        forward_kinematics(design.a, design.b, np.array([10.0, 500, 10, 500, 10, 500]))


def test_jacobian_matches_finite_differences(design, rng):
    P = np.array([[3.0, -2.0, 205.0]])
    R = Rotation.from_rotvec([[0.05, -0.1, 0.2]])
    J = platform_jacobian(design.a, design.b, P, R)[0]
    h = 1e-6
    for i in range(6):
        d = np.zeros(6)
        d[i] = h
        plus = inverse_kinematics(design.a, design.b, P + d[:3], Rotation.from_rotvec(d[3:]) * R)
        minus = inverse_kinematics(design.a, design.b, P - d[:3], Rotation.from_rotvec(-d[3:]) * R)
        assert np.allclose((plus - minus)[0] / (2 * h), J[:, i], atol=1e-7)


def test_jacobian_transpose_is_statics(design):
    """A pure vertical force on the platform is balanced by leg forces f with Jᵀ f = w."""
    P = np.array([[0.0, 0.0, 200.0]])
    R = Rotation.identity(1)
    J = platform_jacobian(design.a, design.b, P, R)[0]
    w = np.array([0, 0, -9.81, 0, 0, 0])
    f = np.linalg.solve(J.T, w)
    assert np.allclose(J.T @ f, w)
    assert np.all(f < 0)  # every leg pushes up (compression) under a weight at the centre
    assert leg_vectors(design.a, design.b, P, R).shape == (1, 6, 3)


def test_condition_number_grows_towards_the_singularity(design):
    """About 5 at home; a rotation about the vertical towards 90° (where the legs of this
    platform fall into a singular configuration) makes it grow without bound."""
    home = np.asarray(design.home.position, float)
    angles = [0.0, 60.0, 85.0, 89.9]
    cond = [
        condition_number(design.a, design.b, home, Rotation.from_rotvec([0, 0, np.deg2rad(g)]))[0]
        for g in angles
    ]
    assert 3.0 < cond[0] < 8.0
    assert np.all(np.diff(cond) > 0)
    assert cond[-1] > 1e3
