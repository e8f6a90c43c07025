"""Batched linear least squares with column scaling."""

from __future__ import annotations

import numpy as np


def lstsq(a: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least-squares solution x (..., n) of ``a x ≈ y`` for a (..., m, n), y (..., m).

    Columns are scaled to unit norm before a QR factorisation (numpy's, batched), which keeps
    mm-sized and length²-sized columns from spoiling the conditioning; the paper's normal
    equations ``(AᵀA)⁻¹Aᵀy`` would square the condition number.
    """
    scale = np.linalg.norm(a, axis=-2, keepdims=True)
    scale = np.where(scale == 0.0, 1.0, scale)
    q, r = np.linalg.qr(a / scale)
    x = np.linalg.solve(r, np.einsum("...mn,...m->...n", q, y)[..., None])[..., 0]
    return x / scale[..., 0, :]


def scaled_singular_values(a: np.ndarray) -> np.ndarray:
    """Singular values (..., n) of ``a`` with unit-norm columns, largest first."""
    scale = np.linalg.norm(a, axis=-2, keepdims=True)
    scale = np.where(scale == 0.0, 1.0, scale)
    return np.linalg.svd(a / scale, compute_uv=False)
