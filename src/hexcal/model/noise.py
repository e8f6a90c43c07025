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
    v = P[:, None, :] + np.einsum("mij,kj->mki", R, b) - a[None]
    n = v / np.linalg.norm(v, axis=-1, keepdims=True)
    g = np.cross(b[None], np.einsum("mji,mkj->mki", R, n))
    return n, g


def leg_covariance(
    a: np.ndarray, b: np.ndarray, P: np.ndarray, R: np.ndarray, sig: NoiseSigmas
) -> np.ndarray:
    """Covariance (M, 6, 6) mm² of the six leg-length residuals of each pose."""
    n, g = pose_sensitivities(a, b, P, R)
    cov = sig.position_mm**2 * n @ n.transpose(0, 2, 1) + sig.orientation_rad**2 * g @ g.transpose(
        0, 2, 1
    )
    return cov + sig.reading_mm**2 * np.eye(a.shape[0])
