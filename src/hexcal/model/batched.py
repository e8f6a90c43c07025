"""Small dense linear algebra (6 × 6) over many poses at once.

numpy's batched ``linalg`` calls LAPACK once per matrix, which for 6 × 6 matrices costs far
more than the arithmetic. Here the matrices are laid out entry-major, ``(k, k, N)``: every
entry is a row over the N poses, and a factorisation is a few hundred whole-row operations,
whatever N.
"""

from __future__ import annotations

import numpy as np


def inverse_cholesky(cov: np.ndarray) -> np.ndarray:
    """L⁻¹ (N, k, k), lower triangular, of symmetric positive definite matrices ``cov``
    (k, k, N), L their lower Cholesky factors (so ``L⁻¹ Σ L⁻ᵀ = I``). Raises
    ``numpy.linalg.LinAlgError`` when one is not positive definite, as
    ``numpy.linalg.cholesky`` does."""
    return _inverse_factor(cov)[0]


def inverse_and_precision(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(W, S): W = L⁻¹ (N, k, k) as :func:`inverse_cholesky`, and the inverse S = WᵀW = Σ⁻¹
    laid out (k, k, N)."""
    W, inv = _inverse_factor(cov)
    k, n = cov.shape[0], cov.shape[-1]
    S = np.empty((k, k, n))
    for r in range(k):
        for c in range(r + 1):
            s = sum(inv[i][r] * inv[i][c] for i in range(r, k))
            S[r, c] = s
            S[c, r] = s
    return W, S


def _inverse_factor(cov: np.ndarray) -> tuple[np.ndarray, list[list[np.ndarray]]]:
    """(W (N, k, k), the same as rows ``inv[r][c]`` (N,) each) of :func:`inverse_cholesky`."""
    k, n = cov.shape[0], cov.shape[-1]
    zero = np.zeros(n)
    L = [[zero] * k for _ in range(k)]
    with np.errstate(invalid="ignore", divide="ignore"):
        for j in range(k):
            d = cov[j, j] - sum((L[j][i] ** 2 for i in range(j)), zero)
            if not np.all(d > 0):
                raise np.linalg.LinAlgError("Matrix is not positive definite")
            L[j][j] = np.sqrt(d)
            for r in range(j + 1, k):
                s = cov[r, j] - sum((L[r][i] * L[j][i] for i in range(j)), zero)
                L[r][j] = s / L[j][j]
    W = np.zeros((n, k, k))
    inv = [[zero] * k for _ in range(k)]
    for r in range(k):
        inv[r][r] = 1.0 / L[r][r]
        W[:, r, r] = inv[r][r]
        for c in range(r):
            s = sum((L[r][i] * inv[i][c] for i in range(c, r)), zero)
            inv[r][c] = -s * inv[r][r]
            W[:, r, c] = inv[r][c]
    return W, inv


#: A matrix whose scaled normal matrix has a pivot below this is rank deficient (a condition
#: number above 1e7).
RANK_TOL = 1e-14


def solve(A: np.ndarray, b: np.ndarray, singular: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """x (N, k) solving ``A x = b`` for A (N, k, k), b (N, k), and ok (N,): False where
    ``|det A| ≤ singular`` or A is rank deficient (:data:`RANK_TOL`); x is 0 there
    (:func:`solve_columns` on A's columns)."""
    k = b.shape[1]
    cols = [np.ascontiguousarray(A[:, :, c].T) for c in range(k)]
    x, ok = solve_columns(cols, np.ascontiguousarray(b.T), singular)
    return x.T, ok


def solve_columns(
    cols: list[np.ndarray], b: np.ndarray, singular: float = 1e-12
) -> tuple[np.ndarray, np.ndarray]:
    """x (k, N) solving ``A x = b`` for the matrices A given by their columns ``cols`` (k of
    them, each (k, N): column c's entries, row by row, over the N matrices) and b (k, N); ok
    (N,) as :func:`solve`.

    Solved through the normal equations ``AᵀA x = Aᵀb`` by Cholesky, the columns of A scaled
    to unit norm first (no pivoting to do per matrix, unlike elimination). That squares the
    condition number: meant for Newton steps on well-posed kinematics (condition in the
    hundreds), where a step good to 1e-10 relative is exact enough — the iteration, not the
    step, sets the final accuracy."""
    k, n = b.shape

    def dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        out = u[0] * v[0]
        for r in range(1, len(u)):
            out += u[r] * v[r]
        return out

    norm = [np.sqrt(dot(c, c)) for c in cols]
    with np.errstate(divide="ignore", invalid="ignore"):
        cols = [c / np.where(s > 0, s, 1.0) for c, s in zip(cols, norm, strict=True)]
    zero = np.zeros(n)
    L = [[zero] * k for _ in range(k)]
    logdet = np.zeros(n)
    ok = np.ones(n, bool)
    with np.errstate(invalid="ignore", divide="ignore"):
        for j in range(k):
            for r in range(j, k):
                s = dot(cols[r], cols[j])
                for i in range(j):
                    s -= L[r][i] * L[j][i]
                if r == j:
                    # A pivot this small relative to its unit column: rank deficient (the
                    # normal equations square the rounding, so the test is on the square).
                    ok &= s > RANK_TOL
                    s = np.sqrt(np.where(s > 0, s, 1.0))
                    logdet += np.log(s)
                    L[j][j] = s
                else:
                    L[r][j] = s / L[j][j]
        # det A = det(scaled A) · Π column norms; det(scaled A)² = Π L_jj².
        for s in norm:
            ok &= s > 0
            logdet += np.log(np.where(s > 0, s, 1.0))
        ok &= logdet > np.log(singular)
        y: list[np.ndarray] = []
        for r in range(k):
            v = dot(cols[r], b)
            for i in range(r):
                v -= L[r][i] * y[i]
            y.append(v / L[r][r])
        x: list[np.ndarray] = [zero] * k
        for r in range(k - 1, -1, -1):
            v = y[r].copy()
            for i in range(r + 1, k):
                v -= L[i][r] * x[i]
            x[r] = v / L[r][r]
    out = np.stack([xr / np.where(s > 0, s, 1.0) for xr, s in zip(x, norm, strict=True)])
    out[:, ~ok] = 0.0
    return out, ok
