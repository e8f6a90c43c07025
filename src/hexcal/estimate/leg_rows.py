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

The poses are held entry-major, the pose axis last ((B, 3, 3, M) for the rotations, (B, 6, 6,
M) for the precisions): every quantity of a leg is then a contiguous row over the poses, and
the normal matrix is summed leg pair by leg pair, ``Σ_c S[k, l] jc[k]ᵀ jc[l]`` as one (7, c) ×
(c, 7) matrix product each — a tenth of the arithmetic of expanding the whitened rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hexcal.estimate.layout import LEGS, ParameterLayout
from hexcal.estimate.lm import scaled_solve

#: Poses per block: large enough that numpy's per-call cost is amortised, small enough that a
#: block's temporaries (about 1 kB per pose) stay in the cache and bounded in memory.
BLOCK = 4096


@dataclass(frozen=True)
class LegData:
    """The measured side of the leg rows, pose axis last: P (B, 3, M) mm, R (B, 3, 3, M)
    (``R[b, i, j]`` over the poses), rho (B, 6, M) mm readings, ``basis`` (B, 6, q, M) of the
    effect parameters (q = 0: none), and the leg offsets ``fixed`` (6,) mm used when they are
    not fitted (Model 36)."""

    P: np.ndarray
    R: np.ndarray
    rho: np.ndarray
    basis: np.ndarray
    fixed: np.ndarray

    @classmethod
    def of(cls, P, R, rho, fixed, basis=None) -> LegData:
        """From one problem's arrays P (M, 3), R (M, 3, 3), rho (M, 6), basis (M, 6, q) (a
        batch axis is added) or a batch's (B, M, …)."""
        P = np.asarray(P, float)
        one = P.ndim == 2
        add = (lambda v: v[None]) if one else (lambda v: v)
        P, R, rho = add(P), add(np.asarray(R, float)), add(np.asarray(rho, float))
        basis = np.zeros((*rho.shape, 0)) if basis is None else add(np.asarray(basis, float))

        def last(v: np.ndarray, axes: tuple[int, ...]) -> np.ndarray:
            return np.ascontiguousarray(v.transpose(axes))

        return cls(
            last(P, (0, 2, 1)),
            last(R, (0, 2, 3, 1)),
            last(rho, (0, 2, 1)),
            last(basis, (0, 2, 3, 1)),
            np.asarray(fixed, float),
        )

    @property
    def n_poses(self) -> int:
        return self.P.shape[-1]

    @property
    def q(self) -> int:
        return self.basis.shape[2]

    def take_batch(self, i: np.ndarray) -> LegData:
        """The problems ``i`` of the batch (all of them when the batch is one problem)."""
        if len(i) == self.P.shape[0]:  # all of them, in order
            return self
        return LegData(self.P[i], self.R[i], self.rho[i], self.basis[i], self.fixed)

    def take(self, rows: np.ndarray | slice) -> LegData:
        """The same data on some poses: ``rows`` index the pose axis."""
        return LegData(
            self.P[..., rows],
            self.R[..., rows],
            self.rho[..., rows],
            self.basis[..., rows],
            self.fixed,
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


def _legs(x: np.ndarray, d: LegData, lay: ParameterLayout, rows: slice):
    """(v (3, B, 6, c) leg vectors mm, length (B, 6, c) mm, R (B, 3, 3, c)) of the poses
    ``rows`` at the geometry of x (B, p)."""
    a, b = lay.a(x), lay.b(x)  # (B, 6, 3)
    R, P = d.R[..., rows], d.P[..., rows]
    # (R b_k)_i = Σ_j b_k,j R_ij: one (6, 3) × (3, c) product per coordinate.
    v = np.stack([b @ R[:, i] + (P[:, i, None] - a[:, :, i, None]) for i in range(3)])
    return v, np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]), R


def _predicted(x: np.ndarray, d: LegData, lay: ParameterLayout, rows: slice) -> np.ndarray:
    """(B, 6, c) mm reading + offset + basis @ θ of the poses ``rows``."""
    off = lay.offsets(x, d.fixed)
    pred = d.rho[..., rows] + (off[..., None] if off.ndim == 2 else off[None, :, None])
    if d.q:
        pred = pred + np.einsum("bkqc,bq->bkc", d.basis[..., rows], lay.effects(x))
    return pred


def leg_terms(x: np.ndarray, d: LegData, lay: ParameterLayout, rows: slice = slice(None)):
    """Residual e (B, 6, c) mm and compact Jacobian jc (B, 6, nc, c) of the poses ``rows``
    at x (B, p): e = geometric length − reading − offset − basis @ θ; jc = d e / d[a_k, b_k,
    offset_k]; the effect columns are ``−basis``."""
    v, length, R = _legs(x, d, lay, rows)
    e = length - _predicted(x, d, lay, rows)
    n = v / length  # (3, B, 6, c)
    nc = 7 if lay.fit_offsets else 6
    jc = np.empty((*e.shape[:2], nc, e.shape[-1]))
    for i in range(3):
        jc[:, :, i] = -n[i]
        # (Rᵀ n)_i = Σ_j R[j, i] n_j: d|v|/db
        jc[:, :, 3 + i] = (
            R[:, 0, i, None] * n[0] + R[:, 1, i, None] * n[1] + R[:, 2, i, None] * n[2]
        )
    if lay.fit_offsets:
        jc[:, :, 6] = -1.0
    return e, jc


def leg_residuals(x: np.ndarray, d: LegData, lay: ParameterLayout) -> np.ndarray:
    """e (B, M, 6) mm at x (B, p): geometric length − reading − offset − basis @ θ."""
    out = np.empty((x.shape[0], d.n_poses, LEGS))
    for start in range(0, d.n_poses, BLOCK):
        rows = slice(start, start + BLOCK)
        _, length, _ = _legs(x, d, lay, rows)
        out[:, rows] = np.swapaxes(length - _predicted(x, d, lay, rows), 1, 2)
    return out


def pose_jacobian(
    x: np.ndarray, lay: ParameterLayout, P, R, rho, fixed
) -> tuple[np.ndarray, np.ndarray]:
    """(e (n, 6) mm, J (n, 6, 6·nc)) at x (p,) for poses P (n, 3) mm, R (n, 3, 3), readings
    rho (n, 6) mm: each leg's residual (:func:`leg_terms`, the effects left out) and its
    derivatives by a_k, b_k (and offset_k when fitted), leg by leg (each leg's block of nc
    columns; the layout's own order is :func:`compact_columns`)."""
    d = LegData.of(P, R, rho, fixed)
    e, jc = leg_terms(x[None], d, lay)  # (1, 6, n), (1, 6, nc, n)
    nc = jc.shape[2]
    out = np.zeros((d.n_poses, LEGS, LEGS * nc))
    for k in range(LEGS):
        out[:, k, k * nc : (k + 1) * nc] = jc[0, k].T
    return e[0].T, out


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


def _accumulate_block(out: Normal, Ac, e, jc, S, basis, lay: ParameterLayout) -> None:
    """Add one block's JᵀSJ, JᵀSe and eᵀSe: the geometry's part of JᵀSJ to ``Ac`` (B, 6, nc,
    6, nc), in the compact columns, the rest to ``out``; e (B, 6, c), jc (B, 6, nc, c),
    S (B, 6, 6, c), basis (B, 6, q, c)."""
    Se = np.einsum("bklc,blc->bkc", S, e)
    out.chi2 += np.einsum("bkc,bkc->b", e, Se)
    for k in range(LEGS):
        for j in range(k, LEGS):
            # Σ_c S[k, j] jc[k] jc[j]ᵀ: leg k's rows against leg j's, one matrix product.
            Ac[:, k, :, j] += jc[:, k] @ np.swapaxes(S[:, k, j, None] * jc[:, j], -1, -2)
    out.g[:, : Ac.shape[1] * Ac.shape[2]] += np.einsum("bkac,bkc->bka", jc, Se).reshape(len(Se), -1)
    if basis.shape[2]:
        eff = lay.effects_slice
        ng = Ac.shape[1] * Ac.shape[2]
        SB = np.einsum("bklc,blqc->bkqc", S, basis)  # (B, 6, q, c)
        cross = -np.einsum("bkac,bkqc->bkaq", jc, SB)
        out.A[:, :ng, eff] += cross.reshape(cross.shape[0], ng, -1)
        out.A[:, eff, eff] += np.einsum("bkqc,bkrc->bqr", basis, SB)
        out.g[:, eff] -= np.einsum("bkqc,bkc->bq", basis, Se)


def leg_normal(
    x: np.ndarray, d: LegData, S: np.ndarray, lay: ParameterLayout, rows: np.ndarray | None = None
) -> Normal:
    """Normal equations (:class:`Normal`) of the leg rows at x (B, p), each pose weighted by
    its precision S (B, 6, 6, M) 1/mm² (:func:`pose_precisions`); ``rows``: only these poses
    (indices)."""
    nb = x.shape[0]
    nc = 7 if lay.fit_offsets else 6
    ng = LEGS * nc
    # Accumulated in the compact order (leg by leg: a_k, b_k, offset_k), mapped to the
    # layout's columns at the end.
    work = Normal.zeros(nb, lay.size)
    Ac = np.zeros((nb, LEGS, nc, LEGS, nc))
    if rows is not None:
        d, S = d.take(rows), S[..., rows]
    for start in range(0, d.n_poses, BLOCK):
        blk = slice(start, start + BLOCK)
        e, jc = leg_terms(x, d, lay, blk)
        _accumulate_block(work, Ac, e, jc, S[..., blk], d.basis[..., blk], lay)
    flat = Ac.reshape(nb, ng, ng)
    upper = np.triu(np.ones((LEGS, LEGS), bool))  # leg pairs j ≥ k were summed
    work.A[:, :ng, :ng] = np.where(
        np.kron(upper, np.ones((nc, nc), bool)), flat, np.swapaxes(flat, 1, 2)
    )
    work.A[:, ng:, :ng] = np.swapaxes(work.A[:, :ng, ng:], 1, 2)
    order = np.concatenate([compact_columns(lay).reshape(-1), np.arange(ng, lay.size)])
    out = Normal.zeros(nb, lay.size)
    out.A[:, order[:, None], order[None, :]] = work.A
    out.g[:, order] = work.g
    out.chi2 = work.chi2
    return out


def leg_gradient(
    x: np.ndarray, d: LegData, S: np.ndarray, lay: ParameterLayout
) -> tuple[np.ndarray, np.ndarray]:
    """(g (B, p) = JᵀSe, χ² (B,)) of the leg rows at x (B, p): :func:`leg_normal` without
    the normal matrix."""
    nb = x.shape[0]
    nc = 7 if lay.fit_offsets else 6
    g = np.zeros((nb, lay.size))
    chi2 = np.zeros(nb)
    cols = compact_columns(lay).reshape(-1)
    for start in range(0, d.n_poses, BLOCK):
        blk = slice(start, start + BLOCK)
        e, jc = leg_terms(x, d, lay, blk)
        Se = np.einsum("bklc,blc->bkc", S[..., blk], e)
        chi2 += np.einsum("bkc,bkc->b", e, Se)
        g[:, cols] += np.einsum("bkac,bkc->bka", jc, Se).reshape(nb, LEGS * nc)
        if d.q:
            g[:, lay.effects_slice] -= np.einsum("bkqc,bkc->bq", d.basis[..., blk], Se)
    return g, chi2


def pose_precisions(
    x: np.ndarray, d: LegData, lay: ParameterLayout, sig
) -> tuple[np.ndarray, np.ndarray]:
    """(W (B, M, 6, 6), S (B, 6, 6, M)) of each pose's six rows at the geometry of x (B, p):
    the whitener (W Σ Wᵀ = I, :func:`hexcal.model.noise.leg_whiteners`) and the precision
    S = WᵀW = Σ⁻¹, pose axis last. The B problems' poses go through as one array, each pose
    with its problem's geometry (one pass over B·M poses, not B passes)."""
    from hexcal.model.noise import leg_precisions

    nb, m = x.shape[0], d.P.shape[-1]
    if nb == 1:
        W, S = leg_precisions(lay.a(x)[0], lay.b(x)[0], d.P[0], d.R[0], sig, poses_last=True)
        return W[None], S[None]

    def per_pose(v: np.ndarray) -> np.ndarray:  # (B, 6, 3) → (6, 3, B·M)
        return np.broadcast_to(v.transpose(1, 2, 0)[..., None], (6, 3, nb, m)).reshape(6, 3, -1)

    P = d.P.transpose(1, 0, 2).reshape(3, -1)
    R = d.R.transpose(1, 2, 0, 3).reshape(3, 3, -1)
    W, S = leg_precisions(per_pose(lay.a(x)), per_pose(lay.b(x)), P, R, sig, poses_last=True)
    S = np.ascontiguousarray(S.reshape(6, 6, nb, m).transpose(2, 0, 1, 3))
    return W.reshape(nb, m, 6, 6), S
