"""Small dense linear algebra over many poses at once, against numpy's LAPACK per matrix."""

from __future__ import annotations

import numpy as np
import pytest

from hexcal.model.batched import inverse_cholesky, solve
from hexcal.model.kinematics import platform_jacobian
from hexcal.sim.simulate import Simulator


def test_inverse_cholesky_is_numpys():
    rng = np.random.default_rng(0)
    F = rng.normal(size=(500, 6, 6))
    cov = F @ np.swapaxes(F, 1, 2) + 0.01 * np.eye(6)
    W = inverse_cholesky(np.ascontiguousarray(cov.transpose(1, 2, 0)))
    want = np.linalg.inv(np.linalg.cholesky(cov))
    assert np.allclose(W, want, rtol=1e-9, atol=1e-9 * np.abs(want).max())
    cov[7] = -np.eye(6)
    with pytest.raises(np.linalg.LinAlgError):
        inverse_cholesky(np.ascontiguousarray(cov.transpose(1, 2, 0)))


def test_solve_on_kinematics_jacobians(design):
    """The Newton steps of forward kinematics: the platform Jacobians over a workspace, one
    made singular (two equal rows), solved as numpy does, the singular one flagged."""
    P, R = Simulator(design).free((2000,), np.random.default_rng(1))
    from scipy.spatial.transform import Rotation

    J = platform_jacobian(design.a, design.b, P, Rotation.from_matrix(R))
    J[3, 4] = J[3, 2]
    b = np.random.default_rng(2).normal(size=(len(J), 6))
    x, ok = solve(J, b)
    good = np.abs(np.linalg.det(J)) > 1e-12
    # numpy's determinant of the singular one is rounding (1e-11 here), not zero.
    good[3] = False
    assert np.array_equal(ok, good)
    want = np.linalg.solve(J[good], b[good][..., None])[..., 0]
    assert np.allclose(x[good], want, rtol=1e-10, atol=1e-12 * np.abs(want).max())
    assert np.all(x[~good] == 0.0)
