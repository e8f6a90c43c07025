"""Batched linear least squares with column scaling."""

from __future__ import annotations

from collections.abc import Sequence
from contextvars import ContextVar

import numpy as np

#: Default method of :func:`lstsq` in the current context ("qr" or "normal").
METHOD: ContextVar[str] = ContextVar("lstsq_method", default="qr")


def lstsq(
    a: np.ndarray,
    y: np.ndarray,
    method: str | None = None,
    rows: Sequence[int] | np.ndarray | None = None,
) -> np.ndarray:
    """Least-squares solution x (..., n) of ``a x ≈ y`` for a (..., m, n), y (..., m).

    Columns are scaled to unit norm first, which keeps mm-sized and length²-sized columns from
    spoiling the conditioning. ``method="qr"`` (numpy's batched QR) is the accurate default;
    ``"normal"`` solves the paper's normal equations ``(AᵀA)⁻¹Aᵀy`` (eq. 7), which squares the
    condition number but is several times faster on large batches — :data:`METHOD` switches the
    default for a whole run (the study uses it).

    ``rows`` (C increasing counts, each ≤ m): the solutions x (..., C, n) of the systems made of
    the first ``rows[c]`` rows, by the normal equations whatever ``method`` — nested systems
    (the study's nested pose sets) share their sums, so that all C cost about one.
    """
    if rows is not None:
        return _lstsq_nested(a, y, np.asarray(rows, int))
    scale = np.linalg.norm(a, axis=-2, keepdims=True)
    scale = np.where(scale == 0.0, 1.0, scale)
    if (method or METHOD.get()) == "normal":
        an = a / scale
        ata = np.swapaxes(an, -1, -2) @ an
        aty = np.swapaxes(an, -1, -2) @ y[..., None]
        return np.linalg.solve(ata, aty)[..., 0] / scale[..., 0, :]
    q, r = np.linalg.qr(a / scale)
    x = np.linalg.solve(r, np.einsum("...mn,...m->...n", q, y)[..., None])[..., 0]
    return x / scale[..., 0, :]


def running_sums(x: np.ndarray, counts: Sequence[int] | np.ndarray, axis: int) -> np.ndarray:
    """The sums of x over its first counts[c] entries along ``axis``, that axis replaced by
    one of length C (counts increasing). The sum between two counts is added to the one
    before, one whole-array addition per count: 3–7× faster than ``cumsum`` along an inner
    axis, which numpy runs as one short loop per element of the other axes."""
    xs = np.moveaxis(x, axis, 0)
    out = np.empty((len(counts), *xs.shape[1:]), dtype=np.result_type(x, float))
    lo = 0
    for c, hi in enumerate(np.asarray(counts, int)):
        part = xs[lo] if hi == lo + 1 else xs[lo:hi].sum(axis=0)
        if c:
            np.add(out[c - 1], part, out=out[c])
        else:
            out[0] = part
        lo = hi
    return np.moveaxis(out, 0, axis)


def _lstsq_nested(a: np.ndarray, y: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """:func:`lstsq` with ``rows``: AᵀA and Aᵀy summed over blocks of g rows (g the greatest
    common divisor of the counts: a pose's rows, or the poses between two counts), cumulated
    over the blocks and read at the counts; each system's columns scaled to unit norm as
    :func:`lstsq` does (the same scaling, applied to the sums)."""
    edges = np.concatenate([[0], rows])
    if np.any(np.diff(edges) <= 0) or edges[-1] > a.shape[-2]:
        raise ValueError(f"rows must increase from 1 to at most {a.shape[-2]}: {rows.tolist()}")
    g = int(np.gcd.reduce(rows))
    m, n = rows[-1], a.shape[-1]
    # (..., blocks, g, n): one small product per block, all blocks in one matmul call.
    blocks = a[..., :m, :].reshape(*a.shape[:-2], m // g, g, n)
    ata = running_sums(np.swapaxes(blocks, -1, -2) @ blocks, rows // g, axis=-3)
    yb = y[..., :m].reshape(*y.shape[:-1], m // g, g, 1)
    aty = running_sums((np.swapaxes(blocks, -1, -2) @ yb)[..., 0], rows // g, axis=-2)
    scale = np.sqrt(np.diagonal(ata, axis1=-2, axis2=-1))
    scale = np.where(scale == 0.0, 1.0, scale)
    scaled = ata / (scale[..., :, None] * scale[..., None, :])
    return np.linalg.solve(scaled, (aty / scale)[..., None])[..., 0] / scale


def scaled_singular_values(a: np.ndarray) -> np.ndarray:
    """Singular values (..., n) of ``a`` with unit-norm columns, largest first."""
    scale = np.linalg.norm(a, axis=-2, keepdims=True)
    scale = np.where(scale == 0.0, 1.0, scale)
    return np.linalg.svd(a / scale, compute_uv=False)
