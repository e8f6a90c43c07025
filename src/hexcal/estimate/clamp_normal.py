"""Normal equations of the whole-robot fit with the clamp rows, the steps' nuisance unknowns
eliminated by their Schur complement.

The unknowns are the parameters x (p: the geometry, the offsets when fitted, the effects) and
each clamped step's nuisance z_s (1–3: :mod:`hexcal.estimate.clamp_rows`). A pose's rows depend
on x and on its own step's z_s only, so the normal matrix is an arrow:

    [ A     B_1 … B_G ]        A (p, p), B_s (p, n_s), C_s (n_s, n_s)
    [ B_sᵀ  C_s       ]

and the step solves the reduced ``(A − Σ B_s C_s⁻¹ B_sᵀ) δx = −(g − Σ B_s C_s⁻¹ g_s)``, then
``δz_s = −C_s⁻¹ (g_s + B_sᵀ δx)``: the work grows with the steps, not their square. The free
poses carry the leg rows only (:mod:`hexcal.estimate.leg_rows`, compact and blocked); the
clamped poses are evaluated by :class:`~hexcal.estimate.clamp_rows.ClampModel` in blocks of
:data:`~hexcal.estimate.leg_rows.BLOCK` poses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hexcal.estimate.clamp_rows import N_NUISANCE, ClampModel, ClampSteps
from hexcal.estimate.layout import ParameterLayout
from hexcal.estimate.leg_rows import (
    BLOCK,
    LegData,
    leg_normal,
    leg_residuals,
    pose_precisions,
)
from hexcal.estimate.lm import scaled_solve

#: Nuisance unknowns of a step at most (Type II's fixed point); smaller blocks are padded.
NZ = 3


@dataclass
class Blocked:
    """Normal equations with per-step blocks (one problem; the batch axis of
    :class:`~hexcal.estimate.lm.System` has length 1): ``A`` (1, p, p), ``g`` (1, p), ``chi2``
    (1,) over x, ``B`` (G, p, 3), ``C`` (G, 3, 3), ``gz`` (G, 3) per step, padded to 3 (the
    padding: C = I, B = gz = 0); ``sizes`` (G,) the steps' nuisance counts."""

    A: np.ndarray
    g: np.ndarray
    chi2: np.ndarray
    B: np.ndarray
    C: np.ndarray
    gz: np.ndarray
    sizes: np.ndarray

    @classmethod
    def zeros(cls, p: int, sizes: np.ndarray) -> Blocked:
        g = len(sizes)
        C = np.zeros((g, NZ, NZ))
        for s, n in enumerate(sizes):
            C[s, n:, n:] = np.eye(NZ - n)
        return cls(
            np.zeros((1, p, p)),
            np.zeros((1, p)),
            np.zeros(1),
            np.zeros((g, p, NZ)),
            C,
            np.zeros((g, NZ)),
            sizes,
        )

    @property
    def used(self) -> np.ndarray:
        """(G, 3) True at the entries of the padded blocks that are unknowns."""
        return np.arange(NZ)[None, :] < self.sizes[:, None]

    def take(self, i: np.ndarray) -> Blocked:
        if len(i) == 0:
            return Blocked(
                self.A[:0], self.g[:0], self.chi2[:0], self.B, self.C, self.gz, self.sizes
            )
        return self

    def put(self, i: np.ndarray, other: Blocked) -> None:
        if len(i):
            self.A, self.g, self.chi2 = other.A, other.g, other.chi2
            self.B, self.C, self.gz = other.B, other.C, other.gz

    def step(self, lam: np.ndarray) -> np.ndarray:
        """δ (1, p + Σ n_s): x's step, then each step's nuisance in step order."""
        lm = float(lam[0])
        A = self.A[0] + lm * np.diag(np.diag(self.A[0]))
        C = self.C + lm * self.C * np.eye(NZ)  # λ diag(C); the padding stays invertible
        Ci = np.linalg.inv(C)
        BCi = self.B @ Ci  # (G, p, 3)
        A_red = A - np.einsum("gpz,gqz->pq", BCi, self.B)
        g_red = self.g[0] - np.einsum("gpz,gz->p", BCi, self.gz)
        dx = scaled_solve(A_red[None], g_red[None], np.zeros(1))[0]
        dz = -np.einsum("gyz,gz->gy", Ci, self.gz + np.einsum("gpz,p->gz", self.B, dx))
        return np.concatenate([dx, dz[self.used]])[None]

    def quad(self, delta: np.ndarray) -> np.ndarray:
        """δᵀ M δ (1,) with M the whole arrow matrix."""
        p = self.A.shape[-1]
        dx, dz = delta[0, :p], self._pad(delta[0, p:])
        q = dx @ self.A[0] @ dx + 2.0 * np.einsum("p,gpz,gz->", dx, self.B, dz)
        return np.array([q + np.einsum("gy,gyz,gz->", dz, self.C, dz)])

    def _pad(self, z: np.ndarray) -> np.ndarray:
        out = np.zeros((len(self.sizes), NZ))
        out[self.used] = z
        return out

    def full(self) -> np.ndarray:
        """The whole normal matrix (p + Σ n_s, p + Σ n_s), nuisance in step order."""
        p = self.A.shape[-1]
        used = self.used
        n = p + int(used.sum())
        M = np.zeros((n, n))
        M[:p, :p] = self.A[0]
        start = p
        for s, k in enumerate(self.sizes):
            blk = slice(start, start + k)
            M[:p, blk] = self.B[s, :, :k]
            M[blk, :p] = self.B[s, :, :k].T
            M[blk, blk] = self.C[s, :k, :k]
            start += k
        return M


class ClampProblem:
    """The clamp fit's rows at fixed whiteners (one covariance pass): the free poses' leg rows
    and the clamped poses' 9-row frames, evaluated as :class:`Blocked` normal equations.

    P (M, 3) mm, R (M, 3, 3), rho (M, 6) mm, basis (M, 6, q); the pass starts at the
    parameters x and the steps' nuisance ``nu`` (:attr:`xf0`: x, then the nuisance, Type I's
    directions as tangent coordinates about ``nu.u``), where the whiteners are evaluated with
    the noise ``sig``.
    """

    def __init__(self, steps: ClampSteps, P, R, rho, fixed, fit_offsets, basis, nu, x, sig):
        self.steps = steps
        u0 = nu.u
        none = ClampSteps(steps.group[:0], steps.leg, steps.kind, steps.label)
        self.template = ClampModel(none, P[:0], R[:0], rho[:0], fixed, fit_offsets, basis[:0], u0)
        xf = np.concatenate([x, self.template.nuisance_vector(nu)])
        self.xf0 = xf
        self.lay = ParameterLayout(fit_offsets, basis.shape[-1])
        self.sizes = np.array([N_NUISANCE[c] for c in steps.kind], int)
        free = steps.group < 0
        self.free = np.flatnonzero(free)
        clamped = np.flatnonzero(~free)
        self.legs = LegData.of(P[free], R[free], rho[free], fixed, basis[free])
        self.W_free, self.S_free = pose_precisions(x[None], self.legs, self.lay, sig)
        self.blocks: list[tuple[ClampModel, np.ndarray, np.ndarray]] = []
        for start in range(0, len(clamped), BLOCK):
            rows = clamped[start : start + BLOCK]
            sub = ClampSteps(steps.group[rows], steps.leg, steps.kind, steps.label)
            model = ClampModel(
                sub, P[rows], R[rows], rho[rows], fixed, fit_offsets, basis[rows], u0
            )
            W = model.whiteners(xf, sig.position_mm, sig.orientation_rad, sig.reading_mm)
            self.blocks.append((model, W, sub.group))

    @property
    def n_rows(self) -> int:
        """Residual rows in use: six per free pose, the clamped poses' masks."""
        return 6 * len(self.free) + sum(int(m.mask.sum()) for m, _, _ in self.blocks)

    def normal(self, xfs: np.ndarray, i: np.ndarray | None = None) -> Blocked:
        """The normal equations at xf (p + Σ n_s,), given as a batch of one (1, p + Σ n_s)."""
        xf = xfs[0]
        p = self.lay.size
        out = Blocked.zeros(p, self.sizes)
        legs = leg_normal(xf[None, :p], self.legs, self.S_free, self.lay)
        out.A += legs.A
        out.g += legs.g
        out.chi2 += legs.chi2
        start_of = p + np.concatenate([[0], np.cumsum(self.sizes)])
        for model, W, group in self.blocks:
            res, jac, _ = model.evaluate(xf, want_jz=False)
            rw = (W @ res[..., None])[..., 0]
            jw = W @ jac
            out.chi2 += float(np.sum(rw**2))
            jx = jw[..., :p]
            out.A[0] += np.einsum("cri,crj->ij", jx, jx)
            out.g[0] += np.einsum("cri,cr->i", jx, rw)
            for s in np.unique(group):
                sel = group == s
                k = self.sizes[s]
                jz = jw[sel][..., start_of[s] : start_of[s] + k]
                js = jx[sel]
                out.B[s, :, :k] += np.einsum("cri,crz->iz", js, jz)
                out.C[s, :k, :k] += np.einsum("cry,crz->yz", jz, jz)
                out.gz[s, :k] += np.einsum("crz,cr->z", jz, rw[sel])
        return out

    def chi2(self, xf: np.ndarray) -> float:
        """χ² at xf: the whitened residual of every row in use, squared and summed."""
        p = self.lay.size
        e = leg_residuals(xf[None, :p], self.legs, self.lay)
        total = float(np.sum((self.W_free @ e[..., None]) ** 2))
        for model, W, _ in self.blocks:
            res, _, _ = model.evaluate(xf, want_jac=False, want_jz=False)
            total += float(np.sum((W @ res[..., None]) ** 2))
        return total
