"""Direct linear forms, beyond the paper: no differencing of consecutive poses.

Differencing pairs (paper eq. 5, 10, 15) correlates neighbouring equations and lets one noisy
pose spoil two rows. Writing each pose's constraint with one extra unknown keeps every pose's
equations independent:

* Type I: ``P_i + R_i b − a − ρ_i u = 0`` with u the unknown common direction (9 unknowns,
  linear because ρ_i is known; |u| = 1 comes out of the data and is not imposed);
* Type II: ``P_i + R_i b − C = 0`` with C the unknown fixed point of B_k (6 unknowns);
* Type III: ``|V_i − a|² = r²`` written as ``2 V_i·a + (r² − |a|²) = |V_i|²`` (algebraic sphere
  fit, 4 unknowns, r the clamped length).

Shapes: ``P`` (..., N, 3) mm, ``R`` (..., N, 3, 3), lengths (..., N) mm.
"""

from __future__ import annotations

import numpy as np

from hexcal.estimate.solvers.linalg import lstsq
from hexcal.estimate.solvers.paper import Counts, platform_point_positions


def type_i_system(
    P: np.ndarray, R: np.ndarray, length: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Rows [R_i, −I, −ρ_i I] (..., 3N, 9) and right side −P_i (..., 3N) for [b; a; u]."""
    eye = np.broadcast_to(np.eye(3), R.shape)
    m = np.concatenate([R, -eye, -length[..., None, None] * eye], axis=-1)
    batch = P.shape[:-2]
    return m.reshape(*batch, -1, 9), -P.reshape(*batch, -1)


def _rows(counts: Counts, per_pose: int) -> np.ndarray | None:
    return None if counts is None else per_pose * np.asarray(counts)


def type_i_direct(P: np.ndarray, R: np.ndarray, length: np.ndarray, counts: Counts = None):
    """(b_k, a_k, u) each (..., 3) from Type I poses with known full lengths ρ_i (mm). With
    ``counts`` (C,), from the first counts[c] poses of each set: (..., C, 3) each."""
    x = lstsq(*type_i_system(P, R, length), rows=_rows(counts, 3))
    return x[..., :3], x[..., 3:6], x[..., 6:]


def type_i_direct_model42(P: np.ndarray, R: np.ndarray, reading: np.ndarray):
    """Type I with an unknown offset: (b_k, u, a_k + Δρ_k u).

    ``R_i b − (a + Δ u) − r_i u = −P_i`` is linear in b, u and the sum ``a + Δ u``, and in
    nothing else: with the direction clamped, a base point and the offset cannot be told apart
    along the leg. Another pose type (Type III or free poses) must separate them.
    """
    b, a_plus, u = type_i_direct(P, R, reading)
    return b, u, a_plus


def type_ii_system(P: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows [R_i, −I] (..., 3N, 6) and right side −P_i (..., 3N) for [b; C]."""
    eye = np.broadcast_to(np.eye(3), R.shape)
    batch = P.shape[:-2]
    return np.concatenate([R, -eye], axis=-1).reshape(*batch, -1, 6), -P.reshape(*batch, -1)


def type_ii_direct(
    P: np.ndarray, R: np.ndarray, counts: Counts = None
) -> tuple[np.ndarray, np.ndarray]:
    """(b_k, C) each (..., 3) mm: platform point and the fixed point it was clamped at
    ((..., C, 3) with ``counts``, as :func:`type_i_direct`)."""
    x = lstsq(*type_ii_system(P, R), rows=_rows(counts, 3))
    return x[..., :3], x[..., 3:]


def sphere_fit(V: np.ndarray, counts: Counts = None) -> tuple[np.ndarray, np.ndarray]:
    """Algebraic sphere fit through V (..., N, 3) mm: centre (..., 3) and radius (...,) mm;
    with ``counts`` (C,), through the first counts[c] points: (..., C, 3) and (..., C).

    The points are centred first so the |V|² column does not dwarf the others (on the mean of
    all N: the fit is the same wherever the origin is, only its rounding is not).
    """
    centre0 = V.mean(axis=-2, keepdims=True)
    w = V - centre0
    m = np.concatenate([2.0 * w, np.ones((*w.shape[:-1], 1))], axis=-1)
    x = lstsq(m, np.einsum("...i,...i->...", w, w), rows=_rows(counts, 1))
    c = x[..., :3]
    r2 = x[..., 3] + np.einsum("...i,...i->...", c, c)
    return c + centre0[..., 0, :] if counts is None else c + centre0, np.sqrt(np.maximum(r2, 0.0))


def type_iii_direct(
    P: np.ndarray, R: np.ndarray, b: np.ndarray, counts: Counts = None
) -> tuple[np.ndarray, np.ndarray]:
    """(a_k (..., 3), clamped length r (...,)) mm from Type III poses and a known b_k
    ((..., C, 3) and (..., C) with ``counts``, as :func:`sphere_fit`)."""
    return sphere_fit(platform_point_positions(P, R, b), counts)
