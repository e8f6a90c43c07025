"""The score test of a missing effect, from normal equations: no matrix with a row per residual.

At the current fit, an effect's columns B (its basis, whitened like the residual) are projected
off the fit's whitened Jacobian J; what is left, ``B⊥``, says whether the effect is
identifiable (the sine of its principal angle to J, the standard error it would have) and how
much of the whitened residual r it explains (the score, Δχ² to first order). Every quantity
the test needs is an inner product — ``JᵀJ``, ``JᵀB``, ``BᵀB``, ``Jᵀr``, ``Bᵀr`` — so it is
accumulated pose block by pose block with the fit's own precisions
(:func:`hexcal.estimate.leg_rows.leg_normal`, the candidates' bases appended as effect columns at
zero): ``B⊥ᵀB⊥ = BᵀB − (JᵀB)ᵀ(JᵀJ)⁺(JᵀB)`` and ``B⊥ᵀr = Bᵀr − (JᵀB)ᵀ(JᵀJ)⁺Jᵀr``. Time is
linear in the poses and memory independent of them, where projecting the (6M, p) whitened
Jacobian took a QR of it per fit.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hexcal.effects import CATALOGUE
from hexcal.estimate.effect_fit import ModelFit, Problem
from hexcal.estimate.layout import ParameterLayout
from hexcal.estimate.leg_rows import LegData, leg_normal

#: Directions of the scaled JᵀJ with a relative eigenvalue below this are not in J's span
#: (what a column of relative size 1e-7 in J's QR would be).
SPAN_TOL = 1e-14


@dataclass
class Projection:
    """A fit's normal equations against the candidates' columns (see the module doc): built
    once per fit, the candidates' blocks added as they are asked for."""

    fit: ModelFit
    jtj: np.ndarray  #: (p, p)
    jtr: np.ndarray  #: (p,)
    inv: np.ndarray  #: (p, p) the pseudo-inverse of JᵀJ on J's span
    blocks: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=dict)
    #: The basis each block was made from (the problem's own array, cached there)
    made_from: dict[str, np.ndarray] = field(default_factory=dict)

    @classmethod
    def of(cls, problem: Problem, fit: ModelFit) -> Projection:
        derived = fit.refinement.derived
        if "projection" not in derived:
            derived["projection"] = cls._build(problem, fit)
        out: Projection = derived["projection"]
        return out

    @classmethod
    def _build(cls, problem: Problem, fit: ModelFit) -> Projection:
        jtj, jtr, _, _, _ = _normal(problem, fit, [])
        return cls(fit, jtj, jtr, span_pinv(jtj))

    def of_effect(self, problem: Problem, name: str):
        """(JᵀB (p, q), BᵀB (q, q), Bᵀr (q,)) of effect ``name``'s columns. The first request
        evaluates every candidate these data carry at once (one pass over the poses)."""
        if name in self.blocks and self.made_from.get(name) is not problem.basis(name):
            # The effect's columns changed since (zero steps located again): ask afresh.
            del self.blocks[name]
        if name not in self.blocks:
            names = [
                n
                for n in CATALOGUE
                if n not in self.fit.effects and n not in self.blocks and not problem.missing(n)
            ]
            if name not in names:
                names.append(name)
            _, _, jtb, btb, btr = _normal(problem, self.fit, names)
            start = 0
            for n in names:
                q = problem.basis(n).shape[-1]
                cols = slice(start, start + q)
                self.blocks[n] = (jtb[:, cols], btb[cols, cols], btr[cols])
                self.made_from[n] = problem.basis(n)
                start += q
        return self.blocks[name]


def span_pinv(gram: np.ndarray) -> np.ndarray:
    """(p, p) the pseudo-inverse of a Gram matrix JᵀJ on J's span, scaled to unit diagonal
    first (the Jacobian's columns differ by orders of magnitude); directions below
    :data:`SPAN_TOL` of the largest are not in the span."""
    d = 1.0 / np.sqrt(np.where(np.diag(gram) > 0, np.diag(gram), 1.0))
    lam, v = np.linalg.eigh(d[:, None] * gram * d[None, :])
    keep = lam > SPAN_TOL * lam.max()
    return d[:, None] * ((v[:, keep] / lam[keep]) @ v[:, keep].T) * d[None, :]


def _normal(problem: Problem, fit: ModelFit, names: list[str]):
    """(JᵀJ, Jᵀr, JᵀB, BᵀB, Bᵀr) at the fit, B the columns of the effects ``names``."""
    ref = fit.refinement
    if ref.whiteners is None or fit.basis is None:
        raise ValueError(f"{fit.model_name}: fitted with clamp rows, it has no score test")
    own = fit.basis
    extra = [problem.basis(n) for n in names]
    basis = np.concatenate([own, *extra], axis=-1) if extra else own
    fit_offsets = "offset" in fit.effects
    lay = ParameterLayout(fit_offsets, basis.shape[-1])
    p = len(ref.x)
    x = np.concatenate([ref.x, np.zeros(basis.shape[-1] - own.shape[-1])])
    meas = problem.meas
    d = LegData.of(
        meas.position,
        problem.R,
        meas.readings,
        problem.design.offsets,
        basis if basis.shape[-1] else None,
    )
    W = ref.whiteners
    S = np.einsum("mrk,mrl->klm", W, W)[None]  # the fit's precisions, pose axis last
    n = leg_normal(x[None], d, S, lay)
    A, g = n.A[0], n.g[0]
    return A[:p, :p], g[:p], A[:p, p:], A[p:, p:], g[p:]


@dataclass(frozen=True)
class Score:
    """The test of one effect's q columns: sines (q,) of their principal angles to J,
    standard errors (q,) once J is projected out, and what the fit's parameters would take
    of each (through ``coef`` (p, q): J⁺B)."""

    sines: np.ndarray
    se: np.ndarray
    coef: np.ndarray
    gram: np.ndarray  #: (q, q) B⊥ᵀB⊥
    btr: np.ndarray  #: (q,) B⊥ᵀr

    def score(self, keep: np.ndarray) -> float:
        """Δχ² the columns ``keep`` (q,) bool would remove, to first order."""
        if not keep.any():
            return 0.0
        g = self.gram[np.ix_(keep, keep)]
        v = self.btr[keep]
        return float(v @ np.linalg.pinv(g) @ v)


def score_columns(problem: Problem, fit: ModelFit, name: str) -> Score:
    """The score test's quantities for effect ``name`` at ``fit`` (see the module doc)."""
    proj = Projection.of(problem, fit)
    jtb, btb, btr = proj.of_effect(problem, name)
    coef = proj.inv @ jtb
    gram = btb - jtb.T @ coef
    gram = 0.5 * (gram + gram.T)
    v = btr - coef.T @ proj.jtr
    norms = np.sqrt(np.maximum(np.diag(btb), 0.0))
    sines = np.sqrt(np.maximum(np.diag(gram), 0.0)) / np.where(norms > 0, norms, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        se = np.sqrt(np.diag(np.linalg.pinv(gram)))
    return Score(sines, se, coef, gram, v)


def column_norms(problem: Problem, fit: ModelFit) -> np.ndarray:
    """(p,) the norms of the fit's whitened Jacobian's columns."""
    return np.sqrt(np.maximum(np.diag(Projection.of(problem, fit).jtj), 0.0))
