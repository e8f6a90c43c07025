"""The whole-robot refinement of many independent sessions at once: the Monte-Carlo study's
free-pose trials (hundreds of sessions of equal length, no effect, no clamp).

The fit and its decisions are :func:`~hexcal.estimate.refine.refine` and
:func:`~hexcal.estimate.calibrate.refine_from_seeds`, with the sessions as one batch of the
Levenberg–Marquardt (:func:`~hexcal.estimate.lm.minimise`), whose problems step independently
and leave the batch as each converges: each session's fit takes the same steps as when fitted
alone, and one batch replaces hundreds of Python-level fits.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from hexcal.estimate.calibrate import RETRY_CHI2_PER_DOF, RETRY_GAIN
from hexcal.estimate.layout import ParameterLayout
from hexcal.estimate.leg_rows import LegData, leg_residuals, pose_precisions
from hexcal.estimate.lm import minimise
from hexcal.estimate.refine import MAX_NFEV, FitStalled, _legs_at
from hexcal.model.noise import NoiseSigmas


def refine_batch(
    P: np.ndarray,
    R: np.ndarray,
    rho: np.ndarray,
    x0: np.ndarray,
    fixed_offsets: np.ndarray,
    fit_offsets: bool,
    sigmas: NoiseSigmas,
    passes: int = 2,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`~hexcal.estimate.refine.refine` of B sessions: P (B, M, 3) mm, R (B, M, 3, 3),
    rho (B, M, 6) mm, starts x0 (B, p) packed by :class:`ParameterLayout` (no effect);
    ``fixed_offsets`` (6,) mm, the offsets of every session when they are not fitted.

    Returns (x (B, p), χ² (B,) with each pose's covariance at the last pass's geometry, and
    converged (B,): False where a pass did not converge or the residual was not finite, as
    ``refine`` raises :class:`FitStalled` for)."""
    lay = ParameterLayout(fit_offsets, 0)
    d = LegData.of(P, R, rho, fixed_offsets)
    x = np.array(x0, float)
    ok = np.ones(len(x), bool)
    W = np.zeros((len(x), 0, 6, 6))
    for _ in range(passes):
        W, S = pose_precisions(x, d, lay, sigmas)
        sol = minimise(partial(_legs_at, d=d, S=S, lay=lay), x, MAX_NFEV)
        ok &= sol.finite & sol.converged
        x = sol.x
    res = leg_residuals(x, d, lay)
    chi2 = np.sum((W @ res[..., None]) ** 2, axis=(-3, -2, -1))
    return x, chi2, ok


def refine_from_seeds_batch(
    P: np.ndarray,
    R: np.ndarray,
    rho: np.ndarray,
    seeds: np.ndarray,
    design: np.ndarray,
    fixed_offsets: np.ndarray,
    fit_offsets: bool,
    sigmas: NoiseSigmas,
) -> np.ndarray:
    """:func:`~hexcal.estimate.calibrate.refine_from_seeds` of B sessions (shapes as
    :func:`refine_batch`): each from its linear seed (seeds (B, p)); a session whose fit stalls
    is fitted again from the design (design (p,)), and one whose χ²/dof exceeds
    :data:`~hexcal.estimate.calibrate.RETRY_CHI2_PER_DOF` too, that fit kept only when its χ²
    is clearly lower. Returns x (B, p); raises :class:`FitStalled` where a session's fit
    stalls from both starts, as ``refine_from_seeds`` does."""
    x, chi2, ok = refine_batch(P, R, rho, seeds, fixed_offsets, fit_offsets, sigmas)
    dof = max(6 * P.shape[1] - x.shape[1], 1)
    first = chi2 / dof
    again = np.flatnonzero(~ok | ~(first <= RETRY_CHI2_PER_DOF))  # NaN fails the test too
    if not len(again):
        return x
    alt, alt_chi2, alt_ok = refine_batch(
        P[again],
        R[again],
        rho[again],
        np.broadcast_to(design, (len(again), len(design))),
        fixed_offsets,
        fit_offsets,
        sigmas,
    )
    stalled = ~ok[again]
    if np.any(stalled & ~alt_ok):
        raise FitStalled([], "the fit converged neither from the linear seed nor from the design")
    # A first fit that stalled takes the design's; one that stopped high keeps its own unless
    # the design's escaped a local minimum (a NaN χ² from the seed counts as failed).
    take = stalled | (alt_ok & ~(alt_chi2 >= RETRY_GAIN * chi2[again]))
    x[again[take]] = alt[take]
    return x
