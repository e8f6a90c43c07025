"""The study's batched weighted fits reach the same optimum as scipy's least_squares, and are
no less precise than the direct forms they start from."""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from test_solvers_paper import K

from hexcal.estimate.solvers import direct, weighted
from hexcal.estimate.solvers.weighted import _inv3_sym, _point_cov
from hexcal.model.noise import NoiseSigmas
from hexcal.sim.simulate import NoiseModel, Simulator

SIG = NoiseSigmas(0.01, np.deg2rad(0.002), 0.002)


def _sim(truth):
    return Simulator(truth, noise=NoiseModel(0.01, 0.002, 0.002))


def assert_same_optimum(sol, x, sl):
    """Same estimate to 1 % of each parameter's standard deviation (pinv: u has a gauge)."""
    sigma = np.sqrt(np.diag(np.linalg.pinv(sol.jac.T @ sol.jac)))[sl]
    assert np.all(np.abs(sol.x[sl] - x) < 0.01 * sigma), (sol.x[sl] - x) / sigma


def test_type_i_matches_least_squares(truth, rng):
    sim = _sim(truth)
    P, R, rho = sim.measure(rng, *sim.type_i(K, (8,), rng))
    length = rho[:, K] + truth.offsets[K]
    b0, a0, u0 = direct.type_i_direct(P, R, length)
    b, a, _u = weighted.refine_type_i(P, R, length, b0, a0, u0, SIG, iterations=6)

    def fun(x):
        uu = x[6:9] / np.linalg.norm(x[6:9])
        cov = _point_cov(R, x[:3], SIG) + SIG.reading_mm**2 * np.outer(uu, uu)
        res = P + R @ x[:3] - x[3:6] - length[:, None] * uu
        return np.einsum("nij,nj->ni", np.linalg.inv(np.linalg.cholesky(cov)), res).ravel()

    # Weights frozen at the solution, as the Gauss-Newton loop has them at convergence.
    sol = least_squares(fun, np.concatenate([b0, a0, u0]), xtol=1e-14, ftol=1e-14)
    assert_same_optimum(sol, np.concatenate([b, a]), slice(0, 6))


def test_type_iii_matches_least_squares(truth, rng):
    sim = _sim(truth)
    P, R, _ = sim.measure(rng, *sim.type_iii(K, (8,), rng))
    b = truth.b[K]
    a0, r0 = direct.type_iii_direct(P, R, b)
    a, r = weighted.refine_type_iii(P, R, b, a0, r0, SIG, iterations=8)
    v = P + R @ b
    cov = _point_cov(R, b, SIG)

    def fun(x):
        d = v - x[:3]
        n = d / np.linalg.norm(d, axis=-1, keepdims=True)
        var = np.einsum("ni,nij,nj->n", n, cov, n)
        return (np.linalg.norm(d, axis=-1) - x[3]) / np.sqrt(var)

    sol = least_squares(fun, np.concatenate([a0, [r0]]), xtol=1e-14, ftol=1e-14)
    assert_same_optimum(sol, np.concatenate([a, [r]]), slice(0, 4))


def test_inverse_by_cofactors(rng):
    m = rng.normal(size=(50, 3, 3))
    s = m @ m.transpose(0, 2, 1) + np.eye(3)
    assert np.allclose(_inv3_sym(s) @ s, np.eye(3), atol=1e-10)


def test_weighted_type_i_not_worse_than_direct(truth, rng):
    """Over 2000 trials the weighted fit's mean squared base-point error is at most the direct
    form's (it is the efficient one among the two by construction)."""
    sim = _sim(truth)
    P, R, rho = sim.measure(rng, *sim.type_i(K, (2000, 8), rng))
    length = rho[..., K] + truth.offsets[K]
    b0, a0, u0 = direct.type_i_direct(P, R, length)
    _b, a, _ = weighted.refine_type_i(P, R, length, b0, a0, u0, SIG)
    mse_d = np.mean(np.sum((a0 - truth.a[K]) ** 2, axis=-1))
    mse_w = np.mean(np.sum((a - truth.a[K]) ** 2, axis=-1))
    # Standard error of an MSE from 2000 samples is about sqrt(2/2000) ≈ 3 % relative.
    assert mse_w < mse_d * 1.1
