"""The seed paper's linear solvers (Daney 1998, §3.2 and §3.3), batched over trials.

Shapes: ``P`` (..., N, 3) mm, ``R`` (..., N, 3, 3), lengths and readings (..., N) mm.

Equation (5) as printed has the wrong sign on the ``a_k`` block. Multiplying equation (4) by
``ρ_i ρ_{i+1}`` gives

    (ρ_i R_{i+1} − ρ_{i+1} R_i) b_k + (ρ_{i+1} − ρ_i) a_k = ρ_{i+1} P_i − ρ_i P_{i+1},

whereas the paper prints ``(ρ_i − ρ_{i+1}) I`` for the second block; with it, noise-free data are
not recovered (tests/test_solvers_paper.py shows both). Equations (10), (15) and (19) are
correct as printed.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from hexcal.estimate.solvers.linalg import lstsq

#: Nested pose sets: the numbers of leading poses (C,) to solve from, or None for all of them.
Counts = Sequence[int] | np.ndarray | None


def eq5_system(P: np.ndarray, R: np.ndarray, length: np.ndarray, printed: bool = False):
    """The stacked system M (..., 3(N−1), 6), N (..., 3(N−1)) of eq. (5) for [b_k; a_k].

    ``length`` is the full leg length ρ_i (reading + known offset). ``printed=True`` builds the
    block as the paper prints it, only to show that it is wrong.
    """
    li, lj = length[..., :-1, None, None], length[..., 1:, None, None]
    eye = np.eye(3)
    m_b = li * R[..., 1:, :, :] - lj * R[..., :-1, :, :]
    m_a = ((li - lj) if printed else (lj - li)) * eye
    rhs = lj[..., 0] * P[..., :-1, :] - li[..., 0] * P[..., 1:, :]
    m = np.concatenate([m_b, np.broadcast_to(m_a, m_b.shape)], axis=-1)
    batch = P.shape[:-2]
    return m.reshape(*batch, -1, 6), rhs.reshape(*batch, -1)


def _pair_rows(counts: Counts, per_pair: int) -> np.ndarray | None:
    """The rows of the differenced systems of the first ``counts`` poses (N − 1 pairs each)."""
    return None if counts is None else per_pair * (np.asarray(counts) - 1)


def type_i_paper(
    P: np.ndarray, R: np.ndarray, length: np.ndarray, counts: Counts = None
) -> tuple[np.ndarray, np.ndarray]:
    """Method 3.2, eq. (4)-(7): (b_k, a_k), each (..., 3) mm, from Type I poses. With
    ``counts`` (C,), from the first counts[c] poses of each set: (..., C, 3) each."""
    m, n = eq5_system(P, R, length)
    x = lstsq(m, n, rows=_pair_rows(counts, 3))
    return x[..., :3], x[..., 3:]


def eq10_system(P: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The stacked system A (..., 3(N−1), 3), B (..., 3(N−1)) of eq. (10) for b_k."""
    a = R[..., 1:, :, :] - R[..., :-1, :, :]
    b = P[..., :-1, :] - P[..., 1:, :]
    batch = P.shape[:-2]
    return a.reshape(*batch, -1, 3), b.reshape(*batch, -1)


def type_ii_paper(P: np.ndarray, R: np.ndarray, counts: Counts = None) -> np.ndarray:
    """Method 3.3.1, eq. (9)-(12): b_k (..., 3) mm from Type II poses ((..., C, 3) with
    ``counts``, as :func:`type_i_paper`)."""
    return lstsq(*eq10_system(P, R), rows=_pair_rows(counts, 3))


def platform_point_positions(P: np.ndarray, R: np.ndarray, b: np.ndarray) -> np.ndarray:
    """V_i = P_i + R_i b_k, (..., N, 3) mm, for b (..., 3)."""
    return P + np.einsum("...nij,...j->...ni", R, b)


def eq15_system(V: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The system C (..., N−1, 3), D (..., N−1) of eq. (15) for a_k from V_i (..., N, 3)."""
    c = V[..., 1:, :] - V[..., :-1, :]
    sq = np.einsum("...i,...i->...", V, V)
    return c, 0.5 * (sq[..., 1:] - sq[..., :-1])


def type_iii_paper(
    P: np.ndarray, R: np.ndarray, b: np.ndarray, counts: Counts = None
) -> np.ndarray:
    """Method 3.3.2, eq. (13)-(17): a_k (..., 3) mm from Type III poses and a known b_k
    ((..., C, 3) with ``counts``, as :func:`type_i_paper`)."""
    return lstsq(*eq15_system(platform_point_positions(P, R, b)), rows=_pair_rows(counts, 1))


def offset_eq19(
    P: np.ndarray, R: np.ndarray, b: np.ndarray, a: np.ndarray, reading: np.ndarray
) -> np.ndarray:
    """Method 3.3.3, eq. (19) averaged over the poses: Δρ_k (...,) mm."""
    v = platform_point_positions(P, R, b) - a[..., None, :]
    return np.mean(np.linalg.norm(v, axis=-1) - reading, axis=-1)
