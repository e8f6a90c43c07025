"""The explorer's leads refitted for real (:mod:`hexcal.diagnosis.explorer`): each added to the
model as an effect (:class:`~hexcal.effects.explored.ExploredEffect`, exactly what the effect
file it writes declares) and the model cross-validated again, so that the figure stated is
what the file gives, a lead that predicts held-out poses worse is not proposed, and the
headline — its covariate, then its shape — is settled on those refits.

Why the refit has the last word: the explorer's own held-out figure
(:meth:`~hexcal.diagnosis.pose_products.ColumnStats.heldout_folds`) projects the geometry out
once, fitted on every pose, and only the shape's coefficients are refitted fold by fold. For a
shape of a few columns the two agree. For one of many columns that shares directions with the
geometry, the explorer's figure flatters it: an 11-knot spline on every leg (84 columns) stated
99.7 % of a dead band's excess and, refitted, left 1.20× the floor where a bend (12 columns)
reaches it; a spline in time (56 columns) led a lab's lagged coolant thermometer (4 columns)
that predicts held-out poses better once both are refitted.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import numpy as np

from hexcal.diagnosis.leads import Lead
from hexcal.diagnosis.scoring import pose_whiteners
from hexcal.diagnosis.selection import HELDOUT_Z, fit_apart, heldout_gain
from hexcal.effects import CATALOGUE
from hexcal.effects.explored import ExploredEffect
from hexcal.estimate.effect_fit import ModelFit, Problem, fit_model

#: Leads refitted for real (their figure stated, "never worse" checked), best ranked first.
N_REFIT = 6
#: The headline lead's plainer shapes refitted for real (:func:`reshaped`): those whose own
#: held-out χ² reaches this share of the lead's, at most :data:`N_RESHAPE` of them.
RESHAPE_SHARE = 0.9
N_RESHAPE = 2
#: A refitted lead ranked lower takes the headline when it predicts held-out poses better by
#: this many standard errors, pose by pose (the paired test of
#: :func:`~hexcal.diagnosis.selection.heldout_gain`): near-ties keep the explorer's ranking
#: and its rules (a measured sensor before the time it follows).
HEADLINE_Z = HELDOUT_Z


@contextlib.contextmanager
def lead_effect(problem: Problem, lead: Lead) -> Iterator[str]:
    """The lead registered as an effect (its name) for as long as the block runs."""
    name, n = lead.effect_name, 1
    while name in CATALOGUE:  # a file of the same name is loaded already
        n += 1
        name = f"{lead.effect_name[:36]}_{n}"
    eff = ExploredEffect(name, lead.covariate.name, lead.shape)
    eff.physics = f"a shape along the {lead.covariate.label}"
    eff.separating_motion = f"poses spreading the {lead.covariate.label} over its range"
    CATALOGUE[name] = eff
    try:
        yield name
    finally:
        CATALOGUE.pop(name, None)
        problem._bases.pop(name, None)
        problem._missing.pop(name, None)


def refit_leads(
    problem: Problem, fit: ModelFit, leads: list[Lead], level: float, notes: list[str]
) -> None:
    """Refit the model with each lead as an effect: its held-out RMS, its fitted curve, the
    refit itself (:attr:`Lead.refit`), and whether it predicts held-out poses worse than the
    model without it (then not proposed, said in ``notes``). ``level``: the noise level the
    held-out χ² is over."""
    effects = fit.effects
    chol = pose_whiteners(problem, fit) if leads else None
    for lead in leads:
        lead.cv_rms_before_mm = fit.cv_rms_mm
        with lead_effect(problem, lead) as name:
            try:
                after = fit_model(problem, (*effects, name), seed_fit=fit)
            except (ValueError, np.linalg.LinAlgError) as exc:
                lead.worse = True
                lead.notes.append(f"its refit failed: {exc}")
                continue
            coef = np.array([p.value for p in after.params if p.name.startswith(name + ".")])
            basis = problem.basis(name)
        lead.refit = after
        lead.cv_rms_after_mm = after.cv_rms_mm
        lead.fitted = basis @ coef if basis.shape[-1] == coef.size else None
        if after.residuals.shape == fit.residuals.shape:
            lead.explained = fit.residuals - after.residuals
        z = heldout_gain(fit, after, chol, level)[1] if chol is not None else 0.0
        if not after.cv_rms_mm < fit.cv_rms_mm:
            lead.worse = True
            lead.notes.append(
                f"not proposed: with it the held-out RMS rises ({1000 * fit.cv_rms_mm:.2f} → "
                f"{1000 * after.cv_rms_mm:.2f} µm): it fits the poses it saw, not the others"
            )
            notes.append(f"{lead.covariate.name}: " + lead.notes[-1])
        elif not z > HELDOUT_Z:
            # As a catalogue effect at the floor: a gain inside the poses' own scatter is no
            # gain another set of poses would keep.
            lead.worse = True
            lead.notes.append(
                f"not proposed: it predicts held-out poses better by {z:.1f} standard errors "
                f"only (held-out RMS {1000 * fit.cv_rms_mm:.2f} → "
                f"{1000 * after.cv_rms_mm:.2f} µm; {HELDOUT_Z:g} needed)"
            )
            notes.append(f"{lead.covariate.name}: " + lead.notes[-1])


def headline(problem: Problem, fit: ModelFit, tested: list[Lead], level: float) -> None:
    """Settle the headline on the refits: of the refitted, proposed leads in ``tested`` (the
    explorer's ranking), a lower one takes the first place where its refit predicts held-out
    poses better than the current first's by :data:`HEADLINE_Z` standard errors, pose by pose,
    and fits apart from it (:func:`~hexcal.diagnosis.selection.fit_apart`; said in its notes);
    ``tested`` is reordered in place."""
    refitted = [t for t in tested if t.proposed and t.refit is not None]
    if len(refitted) < 2:
        return
    chol = pose_whiteners(problem, fit)
    first = refitted[0]
    for t in refitted[1:]:
        assert first.refit is not None and t.refit is not None
        z = heldout_gain(first.refit, t.refit, chol, level)[1]
        # One model written twice (a curve in time and in the pose's rank) is not evidence.
        if z > HEADLINE_Z and fit_apart(first.refit, t.refit, chol, level):
            t.notes.append(
                f"it leads the {first.covariate.label} ({first.shape.describe(first.covariate.unit)}),"
                f" ranked first on the explorer's own figure, since refitted it predicts held-out "
                f"poses better by {z:.1f} standard errors (held-out RMS "
                f"{1000 * first.cv_rms_after_mm:.2f} → {1000 * t.cv_rms_after_mm:.2f} µm)"
            )
            first = t
    if first is not refitted[0]:
        tested.remove(first)
        tested.insert(tested.index(refitted[0]), first)


def reshaped(problem: Problem, fit: ModelFit, tested: list[Lead], level: float) -> None:
    """The headline lead's shape settled on the refit: its plainer alternatives
    (:attr:`Lead.alternatives`) whose own held-out figure reaches :data:`RESHAPE_SHARE` of its
    own are refitted as it was; the one that predicts held-out poses best, if better than the
    lead, takes its place in ``tested``."""
    lead = next((t for t in tested if t.proposed), None)
    if lead is None or not np.isfinite(lead.cv_rms_after_mm):
        return
    plainer = [
        t
        for t in lead.alternatives
        if t.columns < lead.columns and t.heldout >= RESHAPE_SHARE * lead.heldout
    ][:N_RESHAPE]
    if not plainer:
        return
    refit_leads(problem, fit, plainer, level, [])  # a trial: its notes are not the session's
    best = min((t for t in plainer if t.proposed), key=lambda t: t.cv_rms_after_mm, default=None)
    if best is None or not best.cv_rms_after_mm < lead.cv_rms_after_mm:
        return
    unit = lead.covariate.unit
    best.notes = [
        *lead.notes,
        f"its shape chosen on the refit: {best.shape.describe(unit)} ({best.columns} "
        f"parameters) predicts held-out poses better than {lead.shape.describe(unit)} "
        f"({lead.columns}): {1000 * best.cv_rms_after_mm:.2f} against "
        f"{1000 * lead.cv_rms_after_mm:.2f} µm held-out RMS",
    ]
    best.alternatives = [lead, *(t for t in lead.alternatives if t is not best)]
    lead.alternatives = []
    tested[tested.index(lead)] = best
