"""Statistical checks used by the numerical tests: Monte-Carlo against first-order theory.

An estimator's first-order covariance is ``J Σ Jᵀ`` with J its Jacobian with respect to the
measurements (finite differences at noise-free data). A Monte-Carlo sample of T estimates has a
covariance whose trace is within a few ``sqrt(2/T)`` relative of the prediction when the
estimator is unbiased to first order and the noise is small; that is the tolerance used, not a
constant picked to pass.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.spatial.transform import Rotation


def delta_method_cov(
    f: Callable[[np.ndarray], np.ndarray], z0: np.ndarray, sigma: np.ndarray, h: float = 1e-6
):
    """Covariance (p, p) of f(z) for z = z0 + noise of standard deviations sigma (m,), independent."""
    f0 = f(z0)
    jac = np.empty((f0.size, z0.size))
    for i in range(z0.size):
        dz = np.zeros_like(z0)
        dz[i] = h
        jac[:, i] = (f(z0 + dz) - f(z0 - dz)).ravel() / (2 * h)
    return jac @ np.diag(sigma**2) @ jac.T


def trace_ratio_tolerance(trials: int, k: float = 4.0) -> float:
    """Relative tolerance on a covariance trace estimated from ``trials`` samples (k sigmas)."""
    return k * np.sqrt(2.0 / trials)


def _pack(P: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """Measurement vector: positions (3n), orientation perturbations (3n, zero), readings (n)."""
    return np.concatenate([P.ravel(), np.zeros(P.size), rho.ravel()])


def _unpack(z: np.ndarray, R0: np.ndarray):
    n = len(R0)
    P = z[: 3 * n].reshape(n, 3)
    R = R0 @ Rotation.from_rotvec(z[3 * n : 6 * n].reshape(n, 3)).as_matrix()  # platform frame
    return P, R, z[6 * n :]


def spread_matches_theory(sim, solve, P0, R0, leg: int, trials: int = 4000, rng=None):
    """Monte-Carlo estimates of ``solve(P, R, reading)`` over ``trials`` noisy copies of one
    pose set (P0 (n, 3), R0 (n, 3, 3)) against the delta-method covariance.

    Returns (ratio of covariance traces, MC mean (p,), MC covariance (p, p)); the caller
    asserts ``|ratio − 1| < trace_ratio_tolerance(trials)``.
    """
    rng = rng or np.random.default_rng(0)
    noise = sim.noise
    n = len(P0)
    rho_all = sim.readings(P0, R0)
    sigma = np.concatenate(
        [
            np.full(3 * n, noise.sigma_position_mm),
            np.full(3 * n, noise.sigma_orientation_rad),
            np.full(n, noise.sigma_reading_mm),
        ]
    )
    cov = delta_method_cov(lambda z: solve(*_unpack(z, R0)), _pack(P0, rho_all[:, leg]), sigma)
    Pm, Rm, rhom = noise.apply(
        rng,
        np.broadcast_to(P0, (trials, n, 3)),
        np.broadcast_to(R0, (trials, n, 3, 3)),
        np.broadcast_to(rho_all, (trials, n, 6)),
    )
    est = solve(Pm, Rm, rhom[..., leg])
    mc = np.cov(est.T)
    return np.trace(mc) / np.trace(cov), est.mean(axis=0), mc
