"""The leg-length rows of the whole-robot fit, as normal equations accumulated pose block by
pose block.

Row k of a pose is ``|P + R b_k − a_k| − ρ_k − offset_k − basis_k @ θ`` (mm): it depends on
leg k's own a_k, b_k (3 each) and offset_k, and on the effect parameters θ (q) that every row
may share. Its Jacobian is kept in that compact form — (…, 6, 7) per pose, ``[−n, Rᵀn, −1]``
with n the unit leg vector, and the effect columns ``−basis`` (…, 6, q) — and never expanded to
the (6, p) rows of the parameter vector. The pose's six rows are weighted by their precision
``S = Σ⁻¹ = WᵀW`` (6, 6) (:mod:`hexcal.model.noise`: the legs share the pose's tracker noise),
so the normal matrix ``Σ_i J_iᵀ S_i J_i`` (p, p), the gradient ``Σ_i J_iᵀ S_i e_i`` (p,) and
``χ² = Σ_i e_iᵀ S_i e_i`` are summed over blocks of :data:`BLOCK` poses: the work is linear in
the poses, the memory bounded by a block.

Every array may carry a leading batch axis (independent problems of equal size, e.g. the
study's trials): x (B, p), poses (B, M, …), results (B, p, p), (B, p), (B,).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hexcal.estimate.layout import LEGS, ParameterLayout
from hexcal.estimate.lm import scaled_solve

#: Poses per block: large enough that numpy's per-call cost is amortised, small enough that a
#: block's temporaries (about 4 kB per pose) stay in the cache and bounded in memory.
BLOCK = 1024


@dataclass(frozen=True)
class LegData:
    """The measured side of the leg rows: P (B, M, 3) mm, R (B, M, 3, 3), rho (B, M, 6) mm
    readings, ``basis`` (B, M, 6, q) of the effect parameters (q = 0: none), and the leg
    offsets ``fixed`` (6,) mm used when they are not fitted (Model 36)."""

    P: np.ndarray
    R: np.ndarray
    rho: np.ndarray
    basis: np.ndarray
    fixed: np.ndarray

    @classmethod
    def of(cls, P, R, rho, fixed, basis=None) -> LegData:
        """From one problem's arrays (M, …) (a batch axis is added) or a batch's (B, M, …)."""
        P = np.asarray(P, float)
        one = P.ndim == 2
        add = (lambda v: v[None]) if one else (lambda v: v)
        P, R, rho = add(P), add(np.asarray(R, float)), add(np.asarray(rho, float))
        if basis is None:
            basis = np.zeros((*rho.shape, 0))
        else:
            basis = add(np.asarray(basis, float))
        return cls(P, R, rho, basis, np.asarray(fixed, float))

    @property
    def n_poses(self) -> int:
        return self.P.shape[1]

    @property
    def q(self) -> int:
        return self.basis.shape[-1]

    def take_batch(self, i: np.ndarray) -> LegData:
        """The problems ``i`` of the batch (all of them when the batch is one problem)."""
        if len(i) == self.P.shape[0]:  # all of them, in order
            return self
        return LegData(self.P[i], self.R[i], self.rho[i], self.basis[i], self.fixed)

    def take(self, rows: np.ndarray | slice) -> LegData:
        """The same data on some poses: ``rows`` index the pose axis."""
        return LegData(
            self.P[:, rows], self.R[:, rows], self.rho[:, rows], self.basis[:, rows], self.fixed
        )


def compact_columns(lay: ParameterLayout) -> np.ndarray:
    """(6, nc) column of the parameter vector of each leg's compact Jacobian entry: a_k (3),
    b_k (3), then offset_k when fitted (nc = 7, else 6)."""
    cols = [
        [lay.a_column(k, c) for c in range(3)] + [lay.b_column(k, c) for c in range(3)]
        for k in range(LEGS)
    ]
    if lay.fit_offsets:
        for k in range(LEGS):
            cols[k].append(lay.offset_column(k))
    return np.array(cols)


def leg_terms(x: np.ndarray, d: LegData, lay: ParameterLayout, rows: slice = slice(None)):
    """Residual e (B, c, 6) mm and compact Jacobian jc (B, c, 6, nc) of the poses ``rows``
    at x (B, p): e = geometric length − reading − offset − basis @ θ; jc = d e / d[a_k, b_k,
    offset_k]; the effect columns are ``−basis``."""
    P, R, rho = d.P[:, rows], d.R[:, rows], d.rho[:, rows]
    a, b = lay.a(x), lay.b(x)  # (B, 6, 3)
    # R b_k for every leg: (B, c, 3, 3) @ (B, 1, 3, 6) → (B, c, 3, 6), legs last.
    v = R @ np.swapaxes(b, -1, -2)[:, None] + (P[..., None] - np.swapaxes(a, -1, -2)[:, None])
    length = np.sqrt(np.einsum("...ik,...ik->...k", v, v))  # (B, c, 6)
    n = v / length[..., None, :]  # (B, c, 3, 6)
    rtn = np.swapaxes(R, -1, -2) @ n  # Rᵀ n: d|v|/db
    off = lay.offsets(x, d.fixed)
    e = length - rho - (off[:, None] if off.ndim == 2 else off)
    if d.q:
        e = e - np.einsum("bckq,bq->bck", d.basis[:, rows], lay.effects(x))
    nc = 7 if lay.fit_offsets else 6
    jc = np.empty((*e.shape, nc))
    jc[..., 0:3] = -np.swapaxes(n, -1, -2)
    jc[..., 3:6] = np.swapaxes(rtn, -1, -2)
    if lay.fit_offsets:
        jc[..., 6] = -1.0
    return e, jc


def leg_residuals(x: np.ndarray, d: LegData, lay: ParameterLayout) -> np.ndarray:
    """e (B, M, 6) mm at x (B, p): geometric length − reading − offset − basis @ θ."""
    out = np.empty(d.rho.shape)
    for start in range(0, d.n_poses, BLOCK):
        rows = slice(start, start + BLOCK)
        a, b = lay.a(x), lay.b(x)
        v = d.R[:, rows] @ np.swapaxes(b, -1, -2)[:, None]
        v += d.P[:, rows][..., None] - np.swapaxes(a, -1, -2)[:, None]
        off = lay.offsets(x, d.fixed)
        e = np.sqrt(np.einsum("...ik,...ik->...k", v, v)) - d.rho[:, rows]
        e -= off[:, None] if off.ndim == 2 else off
        if d.q:
            e -= np.einsum("bckq,bq->bck", d.basis[:, rows], lay.effects(x))
        out[:, rows] = e
    return out


@dataclass
class Normal:
    """Normal equations of a weighted least-squares problem at one point: ``A`` (B, p, p) =
    JᵀSJ, ``g`` (B, p) = JᵀSe (half the gradient of χ²), ``chi2`` (B,) = eᵀSe. The
    Gauss–Newton step solves ``A δ = −g``."""

    A: np.ndarray
    g: np.ndarray
    chi2: np.ndarray

    @classmethod
    def zeros(cls, batch: int, p: int) -> Normal:
        return cls(np.zeros((batch, p, p)), np.zeros((batch, p)), np.zeros(batch))

    def __iadd__(self, other: Normal) -> Normal:
        self.A += other.A
        self.g += other.g
        self.chi2 += other.chi2
        return self

    def __sub__(self, other: Normal) -> Normal:
        return Normal(self.A - other.A, self.g - other.g, self.chi2 - other.chi2)

    def take(self, i: np.ndarray) -> Normal:
        """Some problems of the batch (``i`` indexes the batch axis)."""
        return Normal(self.A[i], self.g[i], self.chi2[i])

    def put(self, i: np.ndarray, other: Normal) -> None:
        """Replace problems ``i`` of the batch by ``other``'s."""
        self.A[i], self.g[i], self.chi2[i] = other.A, other.g, other.chi2

    def step(self, lam: np.ndarray) -> np.ndarray:
        """The damped Gauss–Newton step δ (B, p) (:func:`hexcal.estimate.lm.scaled_solve`)."""
        return scaled_solve(self.A, self.g, lam)

    def quad(self, delta: np.ndarray) -> np.ndarray:
        """δᵀAδ (B,): the χ² a step δ (B, p) removes, to first order."""
        return np.einsum("bi,bij,bj->b", delta, self.A, delta)


def _accumulate_block(out: Normal, e, jc, W, basis, cols, lay: ParameterLayout) -> None:
    """Add one block's JᵀSJ, JᵀSe and eᵀSe (S = WᵀW) to ``out``.

    Row k of a pose involves only leg k's compact columns, so the whitened Jacobian
    ``(W J)[r, (k, a)] = W[r, k] jc[k, a]`` is an elementwise product (no sum), and the normal
    matrix one matrix product of the block's whitened rows, in the compact column order."""
    bsz, c, _, nc = jc.shape
    rw = np.einsum("bcij,bcj->bci", W, e)
    out.chi2 += np.einsum("bci,bci->b", rw, rw)
    jw = W[..., None] * jc[:, :, None]  # (B, c, 6 rows, 6 legs, nc)
    jw = jw.reshape(bsz, c * LEGS, LEGS * nc)
    if basis.shape[-1]:
        jw = np.concatenate([jw, -(W @ basis).reshape(bsz, c * LEGS, -1)], axis=-1)
    idx = np.concatenate([cols.reshape(-1), np.arange(lay.n_geometry, lay.size)])
    if bsz == 1:  # one problem: a plain matrix product, which BLAS does best
        jw2 = jw[0]
        out.A[0][idx[:, None], idx[None, :]] += jw2.T @ jw2
        out.g[0, idx] += jw2.T @ rw.reshape(-1)
        return
    jt = np.swapaxes(jw, -1, -2)
    out.A[:, idx[:, None], idx[None, :]] += jt @ jw
    out.g[:, idx] += (jt @ rw.reshape(bsz, -1, 1))[..., 0]


def leg_normal(
    x: np.ndarray, d: LegData, W: np.ndarray, lay: ParameterLayout, rows: np.ndarray | None = None
) -> Normal:
    """Normal equations (:class:`Normal`) of the leg rows at x (B, p), each pose whitened by
    W (B, M, 6, 6) (W Σ Wᵀ = I); ``rows``: only these poses (indices)."""
    cols = compact_columns(lay)
    out = Normal.zeros(x.shape[0], lay.size)
    if rows is not None:
        d, W = d.take(rows), W[:, rows]
    for start in range(0, d.n_poses, BLOCK):
        blk = slice(start, start + BLOCK)
        e, jc = leg_terms(x, d, lay, blk)
        _accumulate_block(out, e, jc, W[:, blk], d.basis[:, blk], cols, lay)
    return out


def pose_whiteners(x: np.ndarray, d: LegData, lay: ParameterLayout, sig) -> np.ndarray:
    """W (B, M, 6, 6), W Σ Wᵀ = I, of each pose's six rows at the geometry of x (B, p)
    (:func:`hexcal.model.noise.leg_whiteners`, for a batch)."""
    from hexcal.model.noise import leg_whiteners

    a, b = lay.a(x), lay.b(x)
    return np.stack([leg_whiteners(a[i], b[i], d.P[i], d.R[i], sig) for i in range(x.shape[0])])
