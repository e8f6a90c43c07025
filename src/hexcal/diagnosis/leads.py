"""A lead of the covariate explorer (:mod:`hexcal.diagnosis.explorer`): one shape along one
covariate, scored at the fit in its scopes, cross-validated on held-out poses, and chosen among
a covariate's shapes by the one-standard-error rule — what the explorer's search along single
covariates and its search of products (:mod:`hexcal.diagnosis.interaction_search`) share.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import BSpline

from hexcal.diagnosis.pose_products import ColumnStats, PoseProducts
from hexcal.effects.covariates import Covariate
from hexcal.effects.explored import Shape
from hexcal.effects.interactions import parse_product
from hexcal.effects.lagged import parse_lag, series_of
from hexcal.estimate.effect_fit import ModelFit, Problem
from hexcal.estimate.quantiles import chi2_isf

#: Family-wise false-alarm probability over every covariate and shape tried.
EXPLORE_ALPHA = 1e-3
#: How many of a covariate's significant shapes are cross-validated (best in-sample first).
N_CV = 6
#: Two covariates correlated beyond this are the same quantity on these poses.
SAME_QUANTITY = 0.98


@dataclass
class Lead:
    """One covariate's best shape at the fit."""

    covariate: Covariate
    values: np.ndarray  #: (M, 6) the covariate at each pose and leg
    shape: Shape
    score: float  #: χ² the shape removes in-sample (first order), over the noise level
    threshold: float  #: the score it must exceed to count
    heldout: float  #: χ² it removes from held-out poses (folds), over the noise level
    share: float  #: of the excess χ² over the floor it explains on held-out poses
    significant: bool = False
    #: mm, the held-out RMS of the model with the lead added as an effect (refitted for real),
    #: and without it
    cv_rms_after_mm: float = float("nan")
    cv_rms_before_mm: float = float("nan")
    worse: bool = False  #: the refit predicts held-out poses worse: not proposed
    #: (M, 6) mm the refitted lead's contribution at each pose and leg (the picture's curve)
    fitted: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)
    heldout_se: float = 0.0  #: the held-out figure's standard error (the folds' spread)
    #: (K,) the χ² it removes from each held-out fold, over the noise level
    folds: np.ndarray | None = None
    #: (M, 6, 2) a product covariate's two factors at each pose and leg (its shape's input)
    factors: np.ndarray | None = None
    #: (M, 6) mm what the refit with the lead takes out of the model's residual (the
    #: residual before less after: the lead's contribution less what the geometry, refitted
    #: with it, takes up again)
    explained: np.ndarray | None = None
    #: The covariate's other cross-validated shapes, most held-out χ² first: where a shape of
    #: many columns leads, a plainer one may predict held-out poses better once refitted for
    #: real (:func:`hexcal.diagnosis.explorer.reshaped`)
    alternatives: list[Lead] = field(default_factory=list, repr=False)
    #: The model refitted with the lead as an effect (:mod:`hexcal.diagnosis.lead_refit`)
    refit: ModelFit | None = field(default=None, repr=False)

    def seen_um(self) -> np.ndarray | None:
        """(M, 6) µm the refitted lead as the model's residual sees it: what the refit with
        it takes out of that residual (:attr:`explained`; where only its own contribution is
        known, −(that contribution), the residual being the reading less the prediction),
        each leg's mean left out (the offsets' constant); None before it is refitted. Not the
        contribution alone: the geometry, refitted with the lead, takes up again what it
        shares with it (a bend's straight part), which the residual never showed."""
        if self.explained is not None:
            c = np.asarray(self.explained) * 1000.0
        elif self.fitted is not None:
            c = -np.asarray(self.fitted) * 1000.0
        else:
            return None
        return c - c.mean(axis=0)

    def axis(self) -> tuple[np.ndarray, str, str]:
        """What the lead's picture draws the residual against: ((M, 6) values, their label
        with the unit, their short name). The covariate; for a product (a surface over two
        covariates, no curve along their product) the surface's own fitted value, µm, on
        whose diagonal the residual lies where the lead explains it."""
        cov = self.covariate
        pair = parse_product(cov.name)
        seen = self.seen_um()
        if pair is not None and seen is not None:
            name = f"fitted {' × '.join(pair)} surface"
            return seen, f"{name} (µm)", name
        unit = f" ({cov.unit})" if cov.unit else ""
        return np.asarray(self.values), f"{cov.label}{unit}", cov.name

    @property
    def columns(self) -> int:
        return self.shape.n_params

    @property
    def ranked_by(self) -> float:
        """What ranks the lead: its held-out χ², less one standard error for a step or a bend,
        whose split was searched on every pose (so its held-out figure flatters it: a step
        placed at a signed covariate's zero does no better than the covariate's own sign), and
        for a series through a lag, whose time constant was searched (a lagged thermometer is a
        smooth curve in time: it leads time only where it predicts better beyond that). A
        product's partner was searched too, but a product is a lead only once it has beaten
        its factors fold by fold at a z corrected for that search
        (:mod:`hexcal.diagnosis.interaction_search`): the paired test is its handicap."""
        lagged = parse_lag(self.covariate.name) is not None
        searched = self.shape.kind in ("step", "hinge") or lagged
        return self.heldout - self.heldout_se if searched else self.heldout

    @property
    def effect_name(self) -> str:
        return "by_" + re.sub(r"[^a-z0-9_]", "_", self.covariate.name.lower())[:36]

    @property
    def points_at(self) -> str:
        if self.shape.kind == "sign" and self.covariate.signed:
            return "play in a leg's joints, taken up one way or the other as its load reverses"
        if self.shape.kind == "periodic":
            return f"a cyclic error along the {self.covariate.label} (a scale, a screw, a gear)"
        return self.covariate.points_at

    @property
    def proposed(self) -> bool:
        return self.significant and not self.worse

    def where(self) -> str:
        legs = self.shape.legs
        if len(legs) == 6:
            return "every leg" + (" alike" if self.shape.shared else "")
        return "leg" + "s" * (len(legs) > 1) + " " + ", ".join(map(str, legs))

    def text(self) -> str:
        c = self.covariate
        after = (
            f"; held-out RMS {1000 * self.cv_rms_before_mm:.1f} → "
            f"{1000 * self.cv_rms_after_mm:.1f} µm with it"
            if np.isfinite(self.cv_rms_after_mm)
            else ""
        )
        said = "".join(f"; {n}" for n in self.notes)
        return (
            f"{c.label} ({c.name}; {self.shape.describe(c.unit)} on {self.where()}): explains "
            f"{100 * self.share:.0f} % of the excess on held-out poses (χ² {self.score:.0f} "
            f"in-sample with {self.columns} shape parameters, threshold "
            f"{self.threshold:.0f}{after}){said}"
        )

    def to_dict(self) -> dict:
        c = self.covariate
        return {
            "covariate": c.name,
            "label": c.label,
            "unit": c.unit,
            "points_at": self.points_at,
            "share_of_excess": self.share,
            "chi2": self.score,
            "heldout_chi2": self.heldout,
            "columns": self.columns,
            "threshold": self.threshold,
            "shape": self.shape.to_dict(),
            "significant": self.significant,
            "proposed": self.proposed,
            "effect": self.effect_name,
            "cv_rms_after_mm": _none(self.cv_rms_after_mm),
            "cv_rms_before_mm": _none(self.cv_rms_before_mm),
            "notes": list(self.notes),
        }


def _none(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def covariate_values(problem: Problem, fit: ModelFit, cov: Covariate) -> np.ndarray | None:
    """(M, 6) ``cov`` at ``problem``'s poses, or None when the data cannot carry it (no
    temperature, or one that hardly changed). At the geometry the data carry, as the effect
    written for it evaluates it (:class:`~hexcal.effects.explored.ExploredEffect`)."""
    data = problem.data
    series = series_of(cov.name)
    # The temperature's own covariates (its value, its lag, whether it rose or fell) need one
    # that changed.
    thermal = series in ("temperature", "temperature_change")
    if thermal and (data.temperature is None or np.ptp(data.temperature) < 0.2):
        return None
    values = np.asarray(cov.values(data), float)
    if not np.all(np.isfinite(values)) or np.all(np.ptp(values, axis=0) == 0):
        return None
    return values


def own_columns(shape: Shape, values: np.ndarray) -> np.ndarray:
    """(M, 6, per) leg k's columns of ``shape`` at its values, in row k."""
    return np.stack([shape.columns(values[:, k], k) for k in range(6)], axis=1)


def scoped(
    scorer: PoseProducts,
    cov: Covariate,
    values: np.ndarray,
    shape: Shape,
    tests: int,
    factors: np.ndarray | None = None,
) -> list[tuple[Lead, ColumnStats]]:
    """``shape`` on every leg, and on the legs whose own score exceeds the per-leg threshold
    (a dent or a binding joint is one leg's: a shape on six legs would spend five legs'
    parameters on noise), with their own coefficients and sharing one set; each judged
    against the family-wise threshold. A shared shape is scored on every leg only. Leg J's
    stroke (``stroke_legJ``) is tried on the five other legs only. A product's shape is
    evaluated at its two covariates ``factors`` (M, 6, 2), ``values`` their product."""
    per = shape.per_leg
    full = scorer.stats(own_columns(shape, values if factors is None else factors))
    eye = np.eye(6 * per)
    blocks = [eye[:, k * per : (k + 1) * per] for k in range(6)]
    # Leg J's error along its own reading is the stroke's shape, tried there: another leg's
    # stroke is tried on the five others (cross-talk), so that one quantity has one place.
    allowed = tuple(k for k in range(1, 7) if cov.name != f"stroke_leg{k}")
    whole = shape if len(allowed) == 6 else shape.with_legs(allowed)
    if shape.shared:
        variants = [(whole, full.map(np.sum([blocks[k - 1] for k in allowed], axis=0)))]
    else:
        sel = np.concatenate([blocks[k - 1] for k in allowed], axis=1)
        variants = [(whole, full if len(allowed) == 6 else full.map(sel))]
        leg_threshold = float(chi2_isf(EXPLORE_ALPHA / (6 * tests), per))
        legs = [k for k in allowed if full.map(blocks[k - 1]).score() > leg_threshold]
        if 0 < len(legs) < len(allowed):
            sel = np.concatenate([blocks[leg - 1] for leg in legs], axis=1)
            variants.append((shape.with_legs(tuple(legs)), full.map(sel)))
            if len(legs) > 1:
                summed = np.sum([blocks[leg - 1] for leg in legs], axis=0)
                variants.append((shape.with_legs(tuple(legs), shared=True), full.map(summed)))
    out = []
    for s, st in variants:
        score = st.score()
        threshold = float(chi2_isf(EXPLORE_ALPHA / tests, s.n_params))
        lead = Lead(cov, values, s, score, threshold, float("nan"), float("nan"), factors=factors)
        lead.significant = bool(score > threshold)
        out.append((lead, st))
    return out


def best_of(rows: list[tuple[float, Lead, ColumnStats]], level: float, excess: float) -> Lead:
    """One covariate's lead of its significant shapes ``rows`` (in-sample merit, the lead, its
    column statistics): the :data:`N_CV` best in-sample cross-validated on the held-out folds
    (their χ², its standard error, their share of the ``excess`` χ² over the floor at the noise
    ``level``), then the plainest near the best (:func:`plainest`)."""
    rows = sorted(rows, key=lambda row: -row[0])
    for _, lead, st in rows[:N_CV]:
        folds = st.heldout_folds()
        lead.heldout, lead.folds = float(folds.sum()), folds
        lead.heldout_se = float(np.std(folds, ddof=1) * np.sqrt(len(folds)))
        lead.share = float(lead.heldout * level / excess) if excess > 0 else float("nan")
    tried = [lead for _, lead, _ in rows[:N_CV]]
    chosen = plainest(tried)
    chosen.alternatives = sorted((t for t in tried if t is not chosen), key=lambda t: -t.heldout)
    return chosen


def plainest(leads: list[Lead]) -> Lead:
    """One covariate's shape by the one-standard-error rule of cross-validation (Breiman et
    al., *Classification and Regression Trees*, 1984, §3.4.3; Hastie, Tibshirani & Friedman,
    *The Elements of Statistical Learning*, §7.10), on the paired folds: of the shapes whose
    held-out χ² falls short of the best's by at most the standard error of that difference
    (fold by fold, the same poses held out), the one with the fewest effective parameters — a
    step's split and a period, searched, count as one more each — the better held-out χ² among
    equals. A step on four legs at their own places (8) then leads an 11-knot spline (56) that
    predicts held-out poses no better, and a load's sign (1 a leg) a step at its zero (2)."""
    top = max(leads, key=lambda t: t.heldout)

    def near(t: Lead) -> bool:
        if t is top or t.folds is None or top.folds is None:
            return t is top
        diff = top.folds - t.folds
        return bool(diff.sum() <= np.std(diff, ddof=1) * np.sqrt(len(diff)))

    return min((t for t in leads if near(t)), key=lambda t: (effective(t), -t.heldout))


def effective(lead: Lead) -> int:
    """The lead's parameters, with each searched split, period or partner counted as one."""
    s = lead.shape
    if s.kind in ("step", "hinge"):
        return s.n_params + len(s.legs)
    return s.n_params + (s.kind in ("periodic", "product"))


def beats(lead: Lead, rival: Lead, z: float) -> bool:
    """Whether ``lead`` removes more held-out χ² than ``rival`` by more than ``z`` standard
    errors of their fold-by-fold difference (the same poses held out in both)."""
    if lead.folds is None or rival.folds is None:
        return False
    diff = lead.folds - rival.folds
    se = float(np.std(diff, ddof=1) * np.sqrt(len(diff)))
    return bool(diff.sum() > z * se)


def determined(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether the covariate ``b`` (M, 6) is, leg by leg, a smooth function of ``a`` on these
    poses (a cubic spline with 4 interior knots along ``a`` explains more than
    :data:`SAME_QUANTITY`² of its variance): the room's temperature drifting with the time, a leg's
    length with its stroke. Their product is then a curve along ``a`` alone, which ``a``'s
    own shapes hold; and two leads along them that explain alike are one quantity on these
    poses."""
    res = tot = 0.0
    for k in range(a.shape[1]):
        u, v = a[:, k], b[:, k] - b[:, k].mean()
        tot += float(v @ v)
        distinct = np.unique(u)
        if len(distinct) < 8:
            res += float(v @ v)  # too few values to carry a curve: not determined by them
            continue
        knots = np.quantile(distinct, np.linspace(0, 1, 6)[1:-1])
        t = np.r_[[u.min()] * 4, knots, [u.max()] * 4]
        x = np.column_stack([np.ones(len(u)), BSpline.design_matrix(u, t, 3).toarray()])
        coef, *_ = np.linalg.lstsq(x, v, rcond=None)
        r = v - x @ coef
        res += float(r @ r)
    return tot > 0 and 1.0 - res / tot > SAME_QUANTITY**2
