"""The leg rows' building blocks (hexcal.estimate.leg_rows) checked against each other and
against finite differences: the gradient alone is the normal equations' ``g`` and χ², for
Model 36 and Model 42; the per-pose Jacobian is the residuals' derivative, leg by leg."""

from __future__ import annotations

import numpy as np
import pytest

from hexcal.estimate.layout import ParameterLayout
from hexcal.estimate.leg_rows import (
    LegData,
    compact_columns,
    leg_gradient,
    leg_normal,
    leg_residuals,
    pose_jacobian,
)
from hexcal.sim.robots import left_hand
from hexcal.sim.simulate import Simulator

ROBOT = left_hand()


def _poses(n: int = 9, seed: int = 3):
    """n free poses of the Left Hand robot and readings 0.05 mm off its geometry (so the
    residuals are not zero), with the design's geometry a little off as the point x."""
    sim = Simulator(ROBOT)
    rng = np.random.default_rng(seed)
    P, R = sim.free((n,), rng)
    v = P[:, None] + np.einsum("mij,kj->mki", R, ROBOT.b) - ROBOT.a
    rho = np.linalg.norm(v, axis=-1) - ROBOT.offsets + rng.normal(0, 0.05, (n, 6))
    return P, R, rho, rng


@pytest.mark.parametrize("fit_offsets", [False, True])
def test_the_gradient_alone_is_the_normal_equations_g_and_chi2(fit_offsets):
    """leg_gradient is leg_normal without the normal matrix: the same g and χ², Model 36
    (offsets fixed) and Model 42, a batch of two points, pose precisions of random SPD."""
    P, R, rho, rng = _poses()
    lay = ParameterLayout(fit_offsets=fit_offsets)
    x0 = lay.pack(ROBOT.a, ROBOT.b, ROBOT.offsets) if fit_offsets else lay.pack(ROBOT.a, ROBOT.b)
    x = np.stack([x0 + rng.normal(0, 0.1, x0.shape) for _ in range(2)])
    d = LegData.of(np.stack([P, P]), np.stack([R, R]), np.stack([rho, rho]), ROBOT.offsets)
    m = rng.normal(size=(2, len(P), 6, 6))
    S = np.einsum("bnij,bnkj->bikn", m, m) + 6 * np.eye(6)[None, :, :, None]
    g, chi2 = leg_gradient(x, d, S, lay)
    normal = leg_normal(x, d, S, lay)
    assert np.allclose(g, normal.g, rtol=1e-10, atol=1e-10)
    assert np.allclose(chi2, normal.chi2, rtol=1e-12)


@pytest.mark.parametrize("fit_offsets", [False, True])
def test_the_pose_jacobian_is_the_residuals_derivative_leg_by_leg(fit_offsets):
    """Each leg's block of the per-pose Jacobian (a_k, b_k, offset_k when fitted) against
    central differences of the leg residuals (h = 1e-5 mm), and zero outside its block."""
    P, R, rho, _ = _poses(4)
    lay = ParameterLayout(fit_offsets=fit_offsets)
    x = lay.pack(ROBOT.a, ROBOT.b, ROBOT.offsets) if fit_offsets else lay.pack(ROBOT.a, ROBOT.b)
    e, J = pose_jacobian(x, lay, P, R, rho, ROBOT.offsets)
    d = LegData.of(P, R, rho, ROBOT.offsets)
    assert np.allclose(e, leg_residuals(x[None], d, lay)[0], atol=1e-12)
    cols = compact_columns(lay)
    nc = cols.shape[1]
    h = 1e-5
    for k in range(6):
        for j, c in enumerate(cols[k]):
            up, down = x.copy(), x.copy()
            up[c] += h
            down[c] -= h
            fd = (leg_residuals(up[None], d, lay)[0] - leg_residuals(down[None], d, lay)[0]) / 2 / h
            assert np.allclose(J[:, :, k * nc + j], np.eye(6)[k] * fd[:, [k]], atol=1e-7)
