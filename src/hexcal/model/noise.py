"""Measurement noise and its propagation to leg lengths.

A pose's six leg lengths all depend on the same tracker pose, so their errors are correlated:
the covariance of the six leg-length residuals of one pose is a full 6×6 matrix

    Σ = σ_p² N Nᵀ + σ_θ² G Gᵀ + σ_ρ² I,

with N (6, 3) the unit leg vectors (position noise), G (6, 3) the rows ``b_k × Rᵀ n_k``
(orientation noise, a small rotation about the platform axes) and σ_ρ the encoder noise.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from hexcal.model.batched import inverse_and_precision, inverse_cholesky

if TYPE_CHECKING:
    from hexcal.model.instruments import Instruments


@dataclass(frozen=True)
class NoiseSigmas:
    """One standard deviation each: position (mm, per axis), orientation (rad, per platform
    axis), encoder reading (mm)."""

    position_mm: float
    orientation_rad: float
    reading_mm: float

    @classmethod
    def from_instruments(cls, inst: Instruments) -> NoiseSigmas:
        """From a :class:`hexcal.model.instruments.Instruments`."""
        return cls(
            float(inst.tracker.position_sigma_mm),
            float(np.deg2rad(inst.tracker.orientation_sigma_deg)),
            float(inst.encoders.reading_sigma_mm),
        )


#: Relative weights used when the instruments' noise is not given: a typical optical tracker
#: and encoder. Only their ratios matter; the level is then estimated from the residual.
DEFAULT_SIGMAS = NoiseSigmas(position_mm=0.01, orientation_rad=np.deg2rad(0.002), reading_mm=0.002)


def pose_sensitivities(
    a: np.ndarray, b: np.ndarray, P: np.ndarray, R: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Unit leg vectors N (M, 6, 3) and orientation rows G (M, 6, 3) for poses P (M, 3) mm,
    R (M, 3, 3): ``dL = N dP + G dθ`` with dθ in the platform frame."""
    n, g = _sensitivities(a, b, P, R)
    return np.ascontiguousarray(n.transpose(2, 1, 0)), np.ascontiguousarray(g.transpose(2, 1, 0))


def _sensitivities(
    a: np.ndarray, b: np.ndarray, P: np.ndarray, R: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """N and G of :func:`pose_sensitivities` laid out (3, 6, M): axis, leg, pose, so that the
    covariances below are built from whole rows over the poses."""
    return sensitivities_soa(a, b, P.T, R.transpose(1, 2, 0))


def sensitivities_soa(
    a: np.ndarray, b: np.ndarray, P: np.ndarray, R: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """N and G (3, 6, M) for poses laid out pose axis last: P (3, M) mm, R (3, 3, M); a, b
    (6, 3) mm, or (6, 3, M): each pose its own geometry (a batch of sessions' poses)."""
    if np.ndim(a) == 2:
        a, b = a[..., None], b[..., None]
    v = np.stack(
        [
            R[i, 0] * b[:, 0] + R[i, 1] * b[:, 1] + R[i, 2] * b[:, 2] + (P[i] - a[:, i])
            for i in range(3)
        ]
    )  # (3, 6, M): P + R b_k − a_k
    n = v / np.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)
    # Rᵀ n, then b × Rᵀ n: dL/dθ with θ about the platform's axes.
    u = [R[0, c] * n[0] + R[1, c] * n[1] + R[2, c] * n[2] for c in range(3)]  # (6, M) each
    bx, by, bz = (b[:, c] for c in range(3))
    g = np.stack([by * u[2] - bz * u[1], bz * u[0] - bx * u[2], bx * u[1] - by * u[0]])
    return n, g


def _covariance_soa(n: np.ndarray, g: np.ndarray, sig: NoiseSigmas) -> np.ndarray:
    """Σ (6, 6, M) from N, G laid out (3, 6, M)."""
    m = n.shape[-1]
    cov = np.empty((6, 6, m))
    sp2, st2 = sig.position_mm**2, sig.orientation_rad**2
    for k in range(6):
        for j in range(k + 1):
            c = sp2 * (n[0, k] * n[0, j] + n[1, k] * n[1, j] + n[2, k] * n[2, j])
            c += st2 * (g[0, k] * g[0, j] + g[1, k] * g[1, j] + g[2, k] * g[2, j])
            cov[k, j] = c
            cov[j, k] = c
        cov[k, k] += sig.reading_mm**2
    return cov


def leg_covariance(
    a: np.ndarray, b: np.ndarray, P: np.ndarray, R: np.ndarray, sig: NoiseSigmas
) -> np.ndarray:
    """Covariance (M, 6, 6) mm² of the six leg-length residuals of each pose."""
    out = np.empty((len(P), 6, 6))
    for start in range(0, len(P), BLOCK):
        blk = slice(start, start + BLOCK)
        n, g = _sensitivities(a, b, P[blk], R[blk])
        out[blk] = _covariance_soa(n, g, sig).transpose(2, 0, 1)
    return out


#: Poses per block of the whole-array computations below: their temporaries (a few hundred
#: rows of the block's length) then stay in the cache, several times faster than whole arrays.
BLOCK = 8192


def leg_whiteners(
    a: np.ndarray, b: np.ndarray, P: np.ndarray, R: np.ndarray, sig: NoiseSigmas
) -> np.ndarray:
    """W (M, 6, 6) with ``W Σ Wᵀ = I`` for each pose's :func:`leg_covariance`: the inverse of
    its lower Cholesky factor (lower triangular).

    Computed over the poses at once, entry by entry (a 6 × 6 factorisation is a few hundred
    arithmetic operations; done as whole-array operations over the poses they cost far less
    than one LAPACK call per pose). Raises ``numpy.linalg.LinAlgError`` when a covariance is
    not positive definite, as ``numpy.linalg.cholesky`` does."""
    return leg_precisions(a, b, P, R, sig, precision=False)[0]


def leg_precisions(
    a: np.ndarray,
    b: np.ndarray,
    P: np.ndarray,
    R: np.ndarray,
    sig: NoiseSigmas,
    precision: bool = True,
    poses_last: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """(W (M, 6, 6), S (6, 6, M)): :func:`leg_whiteners` and the precision S = WᵀW = Σ⁻¹ of
    each pose's six leg lengths, 1/mm², laid out pose axis last (empty without
    ``precision``). P (M, 3) mm, R (M, 3, 3), or with ``poses_last`` P (3, M), R (3, 3, M),
    and then a, b may be (6, 3, M): each pose its own geometry (:func:`sensitivities_soa`)."""
    m = P.shape[-1] if poses_last else len(P)
    W = np.empty((m, 6, 6))
    S = np.empty((6, 6, m if precision else 0))
    per_pose = np.ndim(a) == 3
    for start in range(0, m, BLOCK):
        blk = slice(start, start + BLOCK)
        if poses_last:
            ab = (a[..., blk], b[..., blk]) if per_pose else (a, b)
            n, g = sensitivities_soa(*ab, P[:, blk], R[..., blk])
        else:
            n, g = _sensitivities(a, b, P[blk], R[blk])
        cov = _covariance_soa(n, g, sig)
        if precision:
            W[blk], S[..., blk] = inverse_and_precision(cov)
        else:
            W[blk] = inverse_cholesky(cov)
    return W, S
