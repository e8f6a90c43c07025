"""Where an unexplained residual points: the residual explained by shapes along covariates.

When no catalogue effect explains the excess over the noise floor, the physical quantity the
residual follows is what points an engineer at the physics. Every covariate of the library
(:mod:`hexcal.effects.covariates`: the platform's pose, every leg's stroke, the leg's
direction, the load and its products, the direction of motion, time, temperature, the place in
the procedure and the table's own numeric columns) is tried with every shape of
:mod:`hexcal.effects.explored` — a line, a smooth spline (its knot count chosen by
cross-validation), a periodic error at the period a periodogram over the covariate finds, a
step at a split of it, a bend (two lines meeting at a knee), its sign — on the legs whose own
share is significant, on all six, each leg with its own coefficients or all sharing one set;
and every pair of covariates acting together, their product
(:mod:`hexcal.diagnosis.interaction_search`). A lead, its scoring and its cross-validation are
:mod:`hexcal.diagnosis.leads`.

A shape counts when its score at the current fit (the model's own parameters projected out,
:func:`hexcal.diagnosis.scoring.block_score`) exceeds the Bonferroni-corrected χ² threshold over
every shape tried (:data:`EXPLORE_ALPHA`, scores over the session's noise level). Leads are
ranked by what they explain on poses they were not fitted to: the projected residual is
regressed on the projected shape in :data:`~hexcal.diagnosis.pose_products.K_FOLDS` folds of whole poses, and the χ² removed
from each held-out fold is summed (no parameter-count penalty: a shape that fits noise loses
on held-out poses by itself). The best lead of each covariate is then refitted for real as an
effect (:class:`~hexcal.effects.explored.ExploredEffect`, exactly what the effect file it
writes declares): its held-out RMS is the figure stated, and a lead whose refit predicts
held-out poses worse than the model without it is not proposed. Those refits settle the
headline (:mod:`hexcal.diagnosis.lead_refit`): the explorer's own figure projects the geometry
out once, which flatters a shape of many columns, so a lower lead whose refit predicts
held-out poses better, pose by pose, leads instead, and the headline's plainer shapes are
refitted too.

Folds: plain numpy (a permutation of the poses, a fixed seed), not scikit-learn's GroupKFold:
the groups are whole poses (their six readings share the pose's noise), which a reshape gives,
and it would be hexcal's only use of that library.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hexcal.diagnosis.interaction_search import products
from hexcal.diagnosis.lead_refit import N_REFIT, headline, refit_leads, reshaped
from hexcal.diagnosis.leads import (
    SAME_QUANTITY,
    Lead,
    beats,
    best_of,
    covariate_values,
    determined,
    scoped,
)
from hexcal.diagnosis.periodogram import periodogram
from hexcal.diagnosis.pose_products import ColumnStats, PoseProducts
from hexcal.effects import CATALOGUE
from hexcal.effects.covariates import Covariate, library
from hexcal.effects.explored import (
    MAX_HARMONICS,
    ExploredEffect,
    Shape,
    hinge,
    line,
    periodic,
    sign,
    spline,
    step,
)
from hexcal.effects.interactions import parse_product
from hexcal.effects.lagged import parse_lag
from hexcal.estimate.effect_fit import ModelFit, Problem
from hexcal.estimate.quantiles import norm_isf

#: Interior knots of the smooth shapes tried (0: a cubic); cross-validation picks one.
SPLINE_KNOTS = (0, 4, 11)
#: Poses on each side of a step's split at least.
MIN_SIDE = 5
#: A signed covariate's sign (a load reversing) must hold this share of the poses both ways.
MIN_SIGN_SHARE = 0.03
#: A lead leaving more than this share of the excess is said to leave most of it.
MOST = 0.5
#: Periods searched along a periodic covariate: from this share of its span …
MAX_PERIOD_SHARE = 0.6
#: … down to this many poses per period at least (a period needs several poses to be seen).
POSES_PER_PERIOD = 4.0


@dataclass
class Exploration:
    """What the residual follows: every covariate's best shape, the proposed ones first, best
    (most held-out χ² explained) first."""

    tested: list[Lead] = field(default_factory=list)
    level: float = 1.0
    notes: list[str] = field(default_factory=list)

    @property
    def leads(self) -> list[Lead]:
        return [t for t in self.tested if t.proposed]

    @property
    def lead(self) -> Lead | None:
        return self.leads[0] if self.leads else None

    def summary(self) -> str:
        if not self.leads:
            return (
                "the residual follows none of the covariates ("
                + ", ".join(t.covariate.name for t in self.tested)
                + ")"
            )
        text = "the residual follows " + "; ".join(t.text() for t in self.leads[:3])
        best = self.leads[0]
        if best.share < MOST:
            text += (
                f". Even the best lead explains only {100 * best.share:.0f} % of the excess: "
                "what is missing is not one shape along one of these covariates (several "
                "effects, or a quantity hexcal does not record)"
            )
        return text

    def to_dict(self) -> dict:
        return {
            "summary": self.summary(),
            "leads": [t.to_dict() for t in self.leads],
            "tested": [t.to_dict() for t in self.tested],
            "noise_level": self.level,
            "notes": list(self.notes),
        }


def _period(values: np.ndarray, resid: np.ndarray, shared: bool) -> tuple[float, int]:
    """(the period a periodogram of the residual (M, 6) over ``values`` finds — on a grid of
    5 points per resolution element, then refined 20× finer about its peak, since a period
    0.5 % off drifts a quarter turn over 14 cycles; how many independent periods the search
    looked at). ``shared`` (one coefficient for every leg): one periodogram of every leg's
    points together, coherent; otherwise each leg's own, their powers summed (the legs may
    follow the covariate with their own signs and sizes, which one periodogram would cancel)."""
    span = float(np.max(np.ptp(values, axis=0)))
    m = len(values)
    hi = MAX_PERIOD_SHARE * span
    lo = max(span * POSES_PER_PERIOD / m, hi / 200.0)
    if not (span > 0 and lo < hi):
        return 0.0, 0
    if shared:
        series = [(values.T.ravel(), resid.T.ravel())]
    else:
        series = [(values[:, k], resid[:, k]) for k in range(6) if np.ptp(values[:, k]) > 0]

    def power(freqs: np.ndarray) -> np.ndarray:
        return sum((periodogram(u, r, 1.0 / freqs) ** 2 for u, r in series), np.zeros(len(freqs)))

    n = int(np.clip(5 * span * (1 / lo - 1 / hi), 50, 4000))
    freqs = np.linspace(1 / hi, 1 / lo, n)
    best = freqs[int(np.argmax(power(freqs)))]
    step = freqs[1] - freqs[0]
    fine = np.linspace(best - step, best + step, 41)
    best = fine[int(np.argmax(power(fine)))]
    return float(1.0 / best), max(int(span * (1 / lo - 1 / hi)), 1)


def _splits(values: np.ndarray, resid: np.ndarray, shared: bool) -> tuple[np.ndarray, int]:
    """((6,) each leg's split of a step along its covariate ``values`` (M, 6): where the mean
    of its residual (M, 6) shifts most (the CUSUM's peak, :data:`MIN_SIDE` poses a side at
    least); the legs' summed residual along the pooled values when ``shared``; how many
    splits were searched (the tests the step stands for: every split, however correlated
    its neighbours, counted as one)."""
    legs = [None] if shared else range(6)
    out = np.zeros(6)
    tries = 0
    for k in legs:
        u = values[:, 0] if k is None else values[:, k]
        r = resid.sum(axis=1) if k is None else resid[:, k]
        order = np.argsort(u, kind="stable")
        us, rs = u[order], r[order] - r.mean()
        n = len(us)
        # A split only between distinct values (a clamped leg repeats one reading).
        cut = np.flatnonzero(np.diff(us) > 0) + 1
        cut = cut[(cut >= MIN_SIDE) & (cut <= n - MIN_SIDE)]
        if not len(cut):
            return np.zeros(6), 0
        tail = np.cumsum(rs[::-1])[::-1]  # Σ from each row on
        stat = tail[cut] ** 2 / (cut * (n - cut) / n)
        i = int(cut[np.argmax(stat)])
        split = 0.5 * (us[i - 1] + us[i])
        out[:] = split if k is None else out
        if k is not None:
            out[k] = split
        tries = max(tries, len(cut))
    return out, tries


#: Candidate knees of a bend per leg: the covariate's quantiles at these shares.
KNEE_GRID = np.linspace(0.1, 0.9, 17)


def _knees(values: np.ndarray, resid: np.ndarray, shared: bool) -> tuple[np.ndarray, int]:
    """((6,) each leg's knee of a bend along its covariate ``values`` (M, 6): of the
    quantiles :data:`KNEE_GRID` of its distinct values, where a line and the covariate beyond
    the knee fit its residual (M, 6) best; the pooled values and the legs' summed residual
    when ``shared``; how many knees were searched)."""
    legs = [None] if shared else range(6)
    out = np.zeros(6)
    for k in legs:
        u = values.ravel() if k is None else values[:, k]
        r = resid.ravel() if k is None else resid[:, k]
        distinct = np.unique(u)
        if len(distinct) < 2 * MIN_SIDE:
            return np.zeros(6), 0
        knees = np.unique(np.quantile(distinct, KNEE_GRID))
        rc = r - r.mean()
        lin = u - u.mean()
        best, at = -1.0, float(knees[0])
        for q in knees:
            x = np.column_stack([lin, np.maximum(u - q, 0.0)])
            x = x - x.mean(axis=0)
            coef, *_ = np.linalg.lstsq(x, rc, rcond=None)
            gain = float(rc @ (x @ coef))
            if gain > best:
                best, at = gain, float(q)
        out[:] = at if k is None else out
        if k is not None:
            out[k] = at
    return out, len(KNEE_GRID)


def _families(cov: Covariate, values: np.ndarray, resid: np.ndarray) -> list[tuple[Shape, int]]:
    """The shapes tried along ``cov`` (own coefficients per leg and shared), each with the
    number of tests it stands for (a period or a split searched counts its tries)."""
    out: list[tuple[Shape, int]] = []
    scopes = (False, True)
    if cov.discrete:
        return [(sign(shared), 1) for shared in scopes]
    for shared in scopes:
        out.append((line(values, shared), 1))
        out += [(spline(values, n, shared), 1) for n in SPLINE_KNOTS]
        splits, tries = _splits(values, resid, shared)
        if tries:
            out.append((step(splits, shared), tries))
        knees, tries = _knees(values, resid, shared)
        if tries:
            out.append((hinge(values, knees, shared), tries))
        if cov.signed and min((values > 0).mean(), (values < 0).mean()) >= MIN_SIGN_SHARE:
            out.append((sign(shared), 1))
    if cov.periodic:
        for shared in scopes:
            period, tries = _period(values, resid, shared)
            if period > 0:  # the cycle's harmonics too: cross-validation picks how many
                out += [(periodic(period, shared, h), tries) for h in range(1, MAX_HARMONICS + 1)]
    return out


def _held_shapes(fit: ModelFit) -> set[tuple[str, str]]:
    """(covariate, shape) of the explored effects the model holds already."""
    out = set()
    for name in fit.effects:
        eff = CATALOGUE.get(name)
        if isinstance(eff, ExploredEffect):
            out.add((eff.covariate, repr(eff.shape.to_dict())))
    return out


def explore(problem: Problem, fit: ModelFit, s2: float, level: float) -> Exploration:
    """Every covariate's best shape at ``fit`` (see the module docstring): ``s2`` the noise
    level of the floor (for the share of the excess), ``level`` the session's own noise level
    the scores are judged against (at least ``s2``)."""
    scorer = PoseProducts(fit, level)
    excess = fit.chi2 - fit.dof * s2
    held = _held_shapes(fit)
    tried: list[tuple[Covariate, np.ndarray, Shape, int]] = []
    carried: dict[str, tuple[Covariate, np.ndarray]] = {}  # the library's order
    for cov in library(problem.data):
        values = covariate_values(problem, fit, cov)
        if values is None:
            continue
        carried[cov.name] = (cov, values)
        for shape, tries in _families(cov, values, fit.residuals):
            if (cov.name, repr(shape.to_dict())) not in held:
                tried.append((cov, values, shape, tries))
    tests = max(sum(t for *_, t in tried), 1)
    best: dict[str, Lead] = {}
    pending: dict[str, list[tuple[float, Lead, ColumnStats]]] = {}
    for cov, values, shape, _ in tried:
        for lead, st in scoped(scorer, cov, values, shape, tests):
            if lead.significant:
                merit = lead.score - lead.columns * np.log(scorer.n)
                pending.setdefault(cov.name, []).append((merit, lead, st))
            elif cov.name not in best or lead.score > best[cov.name].score:
                best[cov.name] = lead
    for name, rows in pending.items():
        best[name] = best_of(rows, level, excess)
    best.update(products(carried, scorer, list(best.values()), held, tests, excess, level))
    tested = _ranked(list(best.values()), problem, fit)
    out = Exploration(tested, level)
    refit = [t for t in tested if t.significant and t.heldout > 0][:N_REFIT]
    refit_leads(problem, fit, refit, level, out.notes)
    headline(problem, fit, out.tested, level)
    reshaped(problem, fit, out.tested, level)
    for t in tested:
        if t.significant and not t.heldout > 0:
            t.worse = True
            t.notes.append("it fits the poses it saw, not the others (held-out χ² not reduced)")
    out.tested.sort(key=lambda t: not t.proposed)  # stable: the ranking stands
    for t in out.leads:
        t.notes += _default_notes(problem, t.covariate)
    return out


def _ranked(leads: list[Lead], problem: Problem, fit: ModelFit) -> list[Lead]:
    """Significant leads first, most held-out χ² first; where the first two are the same
    quantity on these poses and within a standard error of each other — covariates correlated
    beyond :data:`SAME_QUANTITY` (the time and the place in the procedure when the poses come
    at a steady pace), one a smooth function of the other (a room's temperature cycling in
    time: :func:`~hexcal.diagnosis.leads.determined`), or shapes that explain exactly alike (a step at zero of the force ×
    length² is the force's sign) — the one the library lists first (the plainer, physical
    one) leads, the other named with it."""
    out = sorted(leads, key=lambda t: (not t.significant, -t.ranked_by, -t.score))
    _lag_first(out)
    if len(out) > 1 and out[1].significant:
        a, b = out[0], out[1]
        order = {c.name: i for i, c in enumerate(library(problem.data))}
        close = a.heldout - b.heldout <= a.heldout_se
        # A product is not in the library: it never comes before a single covariate.
        last = len(order)
        if close and order.get(b.covariate.name, last) < order.get(a.covariate.name, last):
            r = float(np.corrcoef(a.values.ravel(), b.values.ravel())[0, 1])
            alike = abs(a.heldout - b.heldout) <= 1e-6 * abs(a.heldout)
            # one a smooth function of the other: a room's temperature cycling in time (not a
            # product against a factor: the product's own test against its factors decides)
            product = parse_product(a.covariate.name) or parse_product(b.covariate.name)
            function = not product and (
                determined(a.values, b.values) or determined(b.values, a.values)
            )
            if abs(r) > SAME_QUANTITY or alike or function:
                why = (
                    f"r {r:.3f}"
                    if abs(r) > SAME_QUANTITY
                    else "they explain exactly alike"
                    if alike
                    else "one is a smooth function of the other"
                )
                b.notes.append(f"or the {a.covariate.label}: the same on these poses ({why})")
                out[0], out[1] = b, a
    return out


#: The chance, over every lagged series tried, that one beats the lead by noise alone.
LAG_ALPHA = 0.05


def _lag_first(out: list[Lead]) -> None:
    """A lagged series handicapped below the lead (:attr:`Lead.ranked_by`) leads after all
    where it predicts held-out poses better than the lead fold by fold, by
    :func:`~hexcal.estimate.quantiles.norm_isf` (:data:`LAG_ALPHA` over the lagged series tried) standard
    errors of the paired difference: the handicap guards a smooth curve in time against a
    lag's searched time constant; a series that follows a lab's sensor better than any curve
    in time, pose by held-out pose, is that sensor's (a coolant the part follows slowly)."""
    sig = [t for t in out if t.significant]
    lagged = [t for t in out if parse_lag(t.covariate.name) is not None]
    if not sig or not lagged or parse_lag(sig[0].covariate.name) is not None:
        return
    z = norm_isf(LAG_ALPHA / len(lagged))
    top = sig[0]
    for t in sorted(lagged, key=lambda t: -t.heldout):
        if t.significant and t.heldout > top.heldout and beats(t, top, z):
            t.notes.append(
                f"it predicts held-out poses better than the {top.covariate.label} by more "
                f"than {z:.1f} standard errors, pose by pose"
            )
            out.remove(t)
            out.insert(0, t)
            return


#: What each robot.json key's default is, in words.
_DEFAULTS = {
    "platform_com_mm": "the weight acting at the platform's origin",
    "ujoint_axes": "each base joint's fixed axis horizontal and across its leg at home",
    "balljoint_axes": "each platform joint's axis horizontal and across its leg at home",
}


def _default_notes(problem: Problem, cov: Covariate) -> list[str]:
    """What the covariate's values rest on that robot.json leaves at its default."""
    return [
        f"its values rest on {key} left at its default ({_DEFAULTS.get(key, 'the default')}): "
        f"state {key} in robot.json as the robot is built, and diagnose again"
        for key in cov.default_keys
        if getattr(problem.design, key, None) is None
    ]
