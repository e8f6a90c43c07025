"""How much of the residual a basis could explain, at a fitted model: the score (Lagrange
multiplier) statistic, its identifiability against the model's own parameters, and the
held-out comparison of two fitted models.

Everything that asks "would this basis explain part of the residual?" goes through here: the
catalogue's candidates (:func:`score_candidate`), the richest model of the outlier search and
the change-point search of :mod:`hexcal.diagnosis.changepoint`; the covariate explorer and the
frame search score in the poses' own terms (:mod:`hexcal.diagnosis.pose_products`), the same
statistic. Effects are linear in their
parameters, so the score is exact to first order: the χ² the basis removes once the model's
own parameters are projected out.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hexcal.diagnosis.score import Projection, column_norms, score_columns
from hexcal.effects import get_effect
from hexcal.estimate.effect_fit import ModelFit, Problem
from hexcal.model.noise import DEFAULT_SIGMAS, leg_covariance

#: Below this sine of the principal angle to the model's Jacobian, a parameter is absorbed
#: outright (a rank failure).
MIN_SINE = 1e-4
#: Otherwise it is separable when its standard error, once the model's parameters are projected
#: out (σ_alone / sin θ), resolves this fraction of its plausible range's half-width.
RESOLVE = 0.1


@dataclass
class Candidate:
    """One catalogue effect not in the model, scored against the current fit."""

    effect: str
    score: float  #: Δχ² the effect would remove, to first order
    identifiable: bool
    available: bool
    reason: str = ""  #: why it is not available / not identifiable
    absorbed_by: list[str] = field(default_factory=list)
    separating_motion: str = ""
    refit: ModelFit | None = None
    delta_bic: float = float("nan")
    explained: float = float("nan")  #: share of the excess χ² explained by the refit
    closes: bool = False  #: the refit (alone or with ``with_effect``) is back at the noise floor
    with_effect: str = ""  #: the second effect the remaining excess needs, if any
    #: The excess the refit leaves lies within what the other catalogue effects explain
    #: together (several effects hiding at once)
    chain: bool = False
    #: Held-out χ² the refit removes (:func:`heldout_gain`): > 0 when it predicts poses it
    #: did not see better than the model without it; and that gain over its standard error
    heldout_dchi2: float = float("nan")
    heldout_z: float = float("nan")

    @property
    def cv_rms_mm_after(self) -> float:
        return self.refit.cv_rms_mm if self.refit is not None else float("nan")


def orthonormal(a: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the columns of ``a`` (rank-deficient columns dropped)."""
    q, r = np.linalg.qr(a)
    keep = np.abs(np.diag(r)) > 1e-10 * max(np.abs(np.diag(r)).max(initial=0.0), 1e-300)
    return q[:, keep]


def jacobian_basis(fit: ModelFit) -> np.ndarray:
    """Orthonormal basis of the fit's whitened Jacobian (what :func:`score_candidate` projects
    out); computed once per fit when several candidates are scored."""
    jw, _, _ = fit.refinement.whitened()
    return orthonormal(jw)


def whitened_columns(fit: ModelFit, basis: np.ndarray) -> np.ndarray:
    """(6M, p): a length basis (M, 6, p) mm per unit, whitened as the fit's residual is (the
    sign of the refinement's residual, reading − predicted, taken into account)."""
    _, _, w = fit.refinement.whitened()
    return np.einsum("mij,mjp->mip", w, -basis).reshape(-1, basis.shape[-1])


def projected_scores(fit: ModelFit, columns: np.ndarray, q: np.ndarray | None = None) -> np.ndarray:
    """(p,) the χ² each whitened column alone (:func:`whitened_columns`) would remove from the
    fit's residual, the model's own parameters projected out: ``(b⊥ᵀ r)² / |b⊥|²`` (0 for a
    column the model absorbs)."""
    _, rw, _ = fit.refinement.whitened()
    q = jacobian_basis(fit) if q is None else q
    perp = columns - q @ (q.T @ columns)
    norm2 = np.einsum("ij,ij->j", perp, perp)
    lead = np.einsum("ij,ij->j", columns, columns)
    dot = perp.T @ rw
    ok = norm2 > (1e-8 * np.maximum(lead, 1e-300))
    return np.where(ok, dot**2 / np.where(ok, norm2, 1.0), 0.0)


def block_score(fit: ModelFit, columns: np.ndarray, q: np.ndarray | None = None) -> float:
    """The χ² a block of whitened columns (6M, p) removes together, the model's parameters
    projected out (the score statistic of the block, χ²(p) under the model)."""
    _, rw, _ = fit.refinement.whitened()
    q = jacobian_basis(fit) if q is None else q
    perp = columns - q @ (q.T @ columns)
    qb = orthonormal(perp) if perp.shape[1] else np.zeros((len(rw), 0))
    return float(np.sum((qb.T @ rw) ** 2))


def score_candidate(
    problem: Problem, fit: ModelFit, name: str, q: Projection | None = None
) -> Candidate:
    """Score test and identifiability of one effect at the current fit, from the fit's normal
    equations (:mod:`hexcal.diagnosis.score`; ``q``: the fit's :class:`Projection`, when
    already made; it is made here otherwise)."""
    eff = get_effect(name)
    why = problem.missing(name)
    if why:
        return Candidate(
            name, 0.0, False, False, reason=why, separating_motion=eff.separating_motion
        )
    ref = fit.refinement
    specs = eff.params(problem.design)
    names = [s.name for s in specs]
    test = score_columns(problem, fit, name)
    sines, se = test.sines, test.se
    half = np.array([(sp.plausible[1] - sp.plausible[0]) / 2 for sp in specs])
    need = needed_resolution(specs)
    unresolved = (sines < MIN_SINE) | ~(se < need)
    absorbed = [names[i] for i in np.where(unresolved)[0]]
    cand = Candidate(
        name,
        test.score(~unresolved),
        identifiable=not absorbed,
        available=True,
        separating_motion=eff.separating_motion,
    )
    if absorbed:
        # Name the model parameters that mimic the worst-absorbed column.
        worst = int(np.argmin(sines))
        share = np.abs(test.coef[:, worst]) * column_norms(problem, fit)
        top = [ref.names[i] for i in np.argsort(-share)[:3]]
        cand.absorbed_by = top
        cand.reason = (
            f"{', '.join(absorbed)} cannot be told apart from {', '.join(top)} with these poses "
            f"(principal angle {np.degrees(np.arcsin(min(sines.min(), 1.0))):.2f}°, standard error "
            f"{_worst(se[unresolved] / half[unresolved]):.2g} of the plausible range); "
            f"record {eff.separating_motion}"
        )
    return cand


def needed_resolution(specs) -> np.ndarray:
    """(p,) the standard error each parameter must reach to count as separable, in its spec
    unit: the spec's own ``resolution``, else :data:`RESOLVE` of its plausible half-width."""
    return np.array(
        [
            r
            if (r := getattr(sp, "resolution", None)) is not None
            else RESOLVE * (sp.plausible[1] - sp.plausible[0]) / 2
            for sp in specs
        ]
    )


def _worst(ratios: np.ndarray) -> float:
    """The largest of ``ratios`` (NaN left out), inf when none is a number (undetermined)."""
    known = ratios[~np.isnan(ratios)]
    return float(known.max()) if known.size else float("inf")


def identifiable_candidates(
    problem: Problem, fit: ModelFit, effects: tuple[str, ...], catalogue
) -> list[Candidate]:
    """Every effect of ``catalogue`` not in ``effects``, scored at ``fit``."""
    q = Projection.of(problem, fit)
    return [score_candidate(problem, fit, n, q) for n in catalogue if n not in effects]


def pose_whiteners(problem: Problem, fit: ModelFit) -> np.ndarray:
    """(M, 6, 6) lower Cholesky factors of each pose's 6×6 leg covariance (the stated noise, or
    the typical instruments' without it) at the fit's geometry."""
    r = fit.refinement
    sig = problem.sigmas if problem.sigmas is not None else DEFAULT_SIGMAS
    return np.linalg.cholesky(leg_covariance(r.a, r.b, problem.meas.position, problem.R, sig))
