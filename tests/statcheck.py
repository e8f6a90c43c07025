"""Statistical checks used by the numerical tests: Monte-Carlo against first-order theory.

An estimator's first-order covariance is ``J Σ Jᵀ`` with J its Jacobian with respect to the
measurements (finite differences at noise-free data). A Monte-Carlo sample of T estimates has a
covariance whose trace is within a few ``sqrt(2/T)`` relative of the prediction when the
estimator is unbiased to first order and the noise is small; that is the tolerance used, not a
constant picked to pass.

The held-out RMS of a model that is right is held to its floor the same way
(:func:`floor_limit`): its mean from the prediction variance of the fitted parameters, k σ
above it with σ from the session's noise covariance.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.estimate.effect_fit import K_FOLDS
from hexcal.model.noise import leg_covariance


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


#: The held-out RMS is held to k = 3 σ above its mean (one-sided: a correct model fails a
#: fresh session with probability 0.13 %); on the tests' 184-pose sessions that is 1.154–1.161
#: × the floor, where a fixed, undeclared 1.15 stood (docs/testing.md).
FLOOR_K = 3.0


def heldout_limit(
    floor_mm: float, sd_rel: float, residuals: int, params: int, k: float = FLOOR_K
) -> float:
    """The held-out RMS (mm) a correct model stays below, k σ above its mean.

    Its mean is ``floor·√(1 + p/n_train)`` (first order: each held-out residual adds the
    prediction variance of p parameters fitted on the other folds' n_train residuals, on
    average p/n_train of the noise's); σ is ``sd_rel`` of that, the relative standard deviation
    of the RMS of the session's noise (:func:`heldout_sd_rel`, :func:`heldout_sd_rel_bound`).
    """
    n_train = residuals * (1.0 - 1.0 / K_FOLDS)
    return floor_mm * np.sqrt(1.0 + params / n_train) * (1.0 + k * sd_rel)


def heldout_sd_rel(problem, refinement) -> float:
    """Relative standard deviation of the RMS of a session's leg residuals from the stated
    noise alone: the mean square of residuals with per-pose covariances C_m (6 × 6,
    :func:`hexcal.model.noise.leg_covariance`) has mean Σ tr C_m / n and variance
    2 Σ tr(C_m²) / n² (a χ²-like sum of correlated Gaussians), and the RMS half its relative
    spread. The six legs of a pose share the tracker's pose noise: about 1.5 independent
    residuals a pose, not 6, so ``1/√(2n)`` over the n residuals would be twice too tight."""
    r = refinement
    c = leg_covariance(r.a, r.b, problem.meas.position, problem.R, problem.sigmas)
    return float(0.5 * np.sqrt(2.0 * np.einsum("mij,mji->", c, c)) / np.einsum("mkk->", c))


def heldout_sd_rel_bound(poses: int) -> float:
    """An upper bound on :func:`heldout_sd_rel` from the pose count alone, for outputs that
    carry no covariance (``--json``): the six residuals of a pose fully correlated, one χ²
    degree of freedom a pose (``1/√(2M)``, 1.2× the covariance's value on the simulated rig)."""
    return 1.0 / np.sqrt(2.0 * poses)


def floor_limit(d, k: float = FLOOR_K, extra_params: int = 0) -> float:
    """The held-out RMS limit (mm, :func:`heldout_limit`) for a diagnosis ``d`` whose model is
    right: σ from its session's covariance (the bound where the noise was estimated), its
    parameters (+ ``extra_params`` for a refit beside it, e.g. the explorer's lead)."""
    problem, r = d.problem, d.fit.refinement
    m = len(problem.meas)
    sd = heldout_sd_rel_bound(m) if problem.sigmas is None else heldout_sd_rel(problem, r)
    return heldout_limit(d.noise_floor_mm, sd, 6 * m, len(r.x) + extra_params, k)


def floor_limit_of(out: dict, k: float = FLOOR_K) -> float:
    """:func:`floor_limit` for ``hexcal diagnose --json`` output: σ from the pose count
    (:func:`heldout_sd_rel_bound`)."""
    m = out["poses_used"]
    sd = heldout_sd_rel_bound(m)
    return heldout_limit(out["noise_floor_mm"], sd, 6 * m, len(out["parameters"]), k)


def pose_floor_limit(floor_mm: float, poses: int, params: int, k: float = FLOOR_K) -> float:
    """The pose error (position RMS over ``poses`` held-out or second-session poses, mm) a
    correct model stays below: :func:`heldout_limit` with σ from the pose count
    (:func:`heldout_sd_rel_bound`: each pose's error a correlated 3-vector, at least one χ²
    degree of freedom a pose) and the mean raised by ``params`` fitted on the session's legs."""
    sd = heldout_sd_rel_bound(poses)
    return heldout_limit(floor_mm, sd, 6 * poses, params, k)
