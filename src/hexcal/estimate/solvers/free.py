"""A linear form for free poses (beyond the paper), so a leg with no clamped set still gets a
seed for the refinement without any guess from the user.

Squaring the inverse kinematics ``|P + R b − a| = ρ + Δ`` gives

    2 (Rᵀ P)·b − 2 P·a − 2 Σ_ij R_ij (a_i b_j) + (|a|² + |b|² − Δ²) − 2 ρ Δ = ρ² − |P|²,

linear in b (3), a (3), the nine products c_ij = a_i b_j, s = |a|² + |b|² − Δ² and Δ: 17 unknowns
(16 when Δ is known). The products are not forced to be consistent with a and b: the result is a
seed that the nonlinear refinement then polishes. It needs at least 17 poses with varied
orientations; 25 or more are advised.
"""

from __future__ import annotations

import numpy as np

from hexcal.estimate.solvers.linalg import lstsq

MIN_POSES = 17


def free_system(P: np.ndarray, R: np.ndarray, reading: np.ndarray, offset: float | None):
    """Design matrix (..., N, 17 or 16) and right side (..., N) for one leg's free-pose form:
    P (..., N, 3) mm, R (..., N, 3, 3), reading (..., N) mm (batched over leading axes)."""
    rtp = np.einsum("...ji,...j->...i", R, P)  # Rᵀ P
    ones = np.ones((*P.shape[:-1], 1))
    cols = [2.0 * rtp, -2.0 * P, -2.0 * R.reshape(*R.shape[:-2], 9), ones]
    rhs = reading**2 - np.einsum("...i,...i->...", P, P)
    if offset is None:
        cols.append(-2.0 * reading[..., None])
    else:
        rhs = rhs + 2.0 * reading * offset
    return np.concatenate(cols, axis=-1), rhs


def free_linear(P: np.ndarray, R: np.ndarray, reading: np.ndarray, offset: float | None = None):
    """(b_k, a_k, Δρ_k) from free poses: P (N, 3) mm, R (N, 3, 3), reading (N,) mm.

    With ``offset`` given (Model 36) Δ is that value; the ρ in the form is then the reading.
    """
    m, y = free_system(P, R, reading, offset)
    x = lstsq(m, y)
    delta = float(x[16]) if offset is None else float(offset)
    return x[:3], x[3:6], delta
