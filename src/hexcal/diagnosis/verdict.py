"""The verdict on one set of poses: which catalogue effect is missing, or none, or an excess no
catalogue effect explains.

1. Fit the model; its χ² against the noise floor says whether the residual exceeds it (at
   :data:`EXCESS_Z` standard deviations of the χ² distribution).
2. Score every catalogue effect not in the model (:func:`hexcal.diagnosis.scoring.score_candidate`)
   and refit the :data:`N_LEADERS` best identifiable ones for real: ΔBIC, the share of the excess
   they explain, and how much better they predict the poses they were not fitted to
   (:func:`hexcal.diagnosis.selection.heldout_gain`).
   (The comparisons and their thresholds live in :mod:`hexcal.diagnosis.selection`.)
3. An effect is named when its evidence is very strong (ΔBIC < :data:`BIC_STRONG`) and

   - when the excess is significant: it explains most of it (:data:`MOST`) and brings the
     residual to the floor, alone or with one more effect; or it explains a clear share
     (:data:`CLEAR`), predicts held-out poses better, and the rest of the excess lies within
     what the other catalogue effects explain together (several effects hiding at once: each
     is named in turn, and ``--auto`` goes on). An effect that merely nibbles at a structured
     residual nothing else in the catalogue explains is not the answer;
   - when it is not: it predicts held-out poses significantly better than the model without it
     (:data:`HELDOUT_Z`). At the floor, strong in-sample evidence alone can be a look-alike
     fitting noise and what the geometry almost absorbs.

   Among the effects named, the lowest ΔBIC is the verdict; every refitted effect that fits
   alike (χ² within :data:`ALIKE_DCHI2`, or the poses' χ² inside their noise by Vuong's
   test: :func:`hexcal.diagnosis.selection.alike`) is named with it, so the parameter count
   alone does not pick one of two explanations the data cannot tell apart.
4. Otherwise ``unexplained`` when the excess is significant (the diagnosis then says where it
   points, or that the stated noise looks too low), else ``none``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hexcal.diagnosis.changepoint import ChangePoint
from hexcal.diagnosis.frame_search import FrameChange
from hexcal.diagnosis.locators import locate_candidates
from hexcal.diagnosis.outliers import OutlierSearch, robust_level
from hexcal.diagnosis.score import Projection
from hexcal.diagnosis.scoring import (
    Candidate,
    block_score,
    identifiable_candidates,
    pose_whiteners,
    score_candidate,
    whitened_columns,
)
from hexcal.diagnosis.selection import (
    BIC_STRONG,
    HELDOUT_Z,
    bic_delta,
    heldout_gain,
    wins,
)
from hexcal.diagnosis.selection import alike as alike_to
from hexcal.effects import CATALOGUE, get_effect
from hexcal.estimate.accuracy import floor_cap
from hexcal.estimate.effect_fit import ModelFit, Problem, cross_validated, fit_model, noise_floor
from hexcal.model.noise import DEFAULT_SIGMAS, NoiseSigmas, leg_covariance
from hexcal.vocabulary import Outcome, Verdict

#: The residual exceeds the floor when χ²/dof is this many standard deviations of the χ²
#: distribution above 1. Over clean simulated sessions the fitted χ²/dof spreads 15 % wider
#: than theory (the whitening uses estimated geometry), hence 4 rather than 3.
EXCESS_Z = 4.0
#: How many leaders are refitted.
N_LEADERS = 3


@dataclass
class Judgement:
    """What :func:`judge` decides on one set of poses (mm throughout)."""

    verdict: Verdict
    fit: ModelFit
    candidates: list[Candidate]
    floor: np.ndarray  #: (M, 6) mm the noise alone gives each residual
    floor_source: str
    s2: float  #: the noise level the floor is relative to (1 with the stated noise)
    excess: bool  #: the residual exceeds the floor significantly
    chi2_per_dof: float  #: over the floor
    #: Other effects that fit as well as the verdict's (named with it)
    alike: list[str] = field(default_factory=list)
    #: Changes of a leg's zero located at the fit (the ``zero_step`` effect's times)
    changes: list[ChangePoint] = field(default_factory=list)
    #: s² of the residual from its median pose (:func:`~hexcal.diagnosis.outliers.robust_level`)
    level: float = 1.0
    #: The factor (≤ 1) an estimated floor was capped by (:func:`~hexcal.estimate.accuracy.floor_cap`)
    floor_scale: float = 1.0
    #: A rigid move of the tracker located at the fit (the ``frame_step`` effect's time)
    frame: FrameChange | None = None


def of_the_session(name: str) -> bool:
    """A property of the session (the tracker drifting), not of the robot: such an effect is
    fitted to calibrate from this session but not carried into the calibrated model."""
    return bool(getattr(get_effect(name), "of_the_session", False))


def scaled(sig: NoiseSigmas, s: float) -> NoiseSigmas:
    """The noise ``sig`` scaled by ``s``."""
    return NoiseSigmas(s * sig.position_mm, s * sig.orientation_rad, s * sig.reading_mm)


def judge(
    problem: Problem,
    effects: tuple[str, ...],
    sig: NoiseSigmas | None,
    notes: list[str],
    fit: ModelFit | None = None,
    outliers: OutlierSearch | None = None,
) -> Judgement:
    """Fit (unless ``fit`` is given), score, refit the leaders and decide, on ``problem``'s
    poses (see the module docstring). Notes are appended to ``notes``. The fits the
    ``outliers`` search made on these poses are reused, not made again."""
    rich = None
    if fit is None:
        made = outliers.fit if outliers is not None else None
        if made is not None and made.effects == effects:
            fit, rich = cross_validated(problem, made), outliers.rich if outliers else None
        else:
            fit = fit_model(problem, effects)
    level = robust_level(problem, fit)
    found = locate_candidates(problem, fit, level, effects)
    changes: list[ChangePoint] = found.get("zero_step", [])
    frame = next(iter(found.get("frame_step", [])), None)
    candidates = identifiable_candidates(problem, fit, effects, CATALOGUE)
    _refit_leaders(problem, fit, candidates, effects)
    floor, floor_source, s2, floor_scale = _floor(
        problem, fit, effects, candidates, sig, notes, rich
    )
    expected = fit.dof * s2  # χ² the current fit would have from noise alone
    chi2_per_dof = fit.chi2 / expected
    band = 1.0 + EXCESS_Z * np.sqrt(2.0 / fit.dof)
    excess = bool(chi2_per_dof > band)
    _weigh(problem, fit, candidates, s2, excess, band)
    winners = [c for c in candidates if wins(c, excess)]
    best = min(winners, key=lambda c: c.delta_bic) if winners else None
    if best is not None and of_the_session(best.effect):
        best = _robot_before_session(best, candidates, winners, excess, notes)
    verdict: Verdict
    alike: list[str] = []
    if best is not None:
        verdict = best.effect
        alike = alike_to(lambda: pose_whiteners(problem, fit), best, candidates, s2)
        notes.extend(_look_alike(problem, best))
        notes.extend(_named_notes(best, alike, fit, candidates, s2))
    elif excess:
        verdict = Outcome.UNEXPLAINED
        helpful = [c for c in candidates if c.refit is not None and c.delta_bic < BIC_STRONG]
        if helpful:
            notes.append(
                "some effects help but none brings the residual to the noise floor, alone or "
                "with other catalogue effects: "
                + ", ".join(
                    f"{c.effect} (explains {100 * c.explained:.0f} % of the excess, leaves "
                    f"χ²/dof {c.refit.chi2 / (c.refit.dof * s2):.2f})"
                    for c in helpful
                    if c.refit is not None
                )
            )
    else:
        verdict = Outcome.NONE
        _note_heldout_refusals(candidates, notes)
    return Judgement(
        verdict,
        fit,
        candidates,
        floor,
        floor_source,
        s2,
        excess,
        float(chi2_per_dof),
        alike,
        changes,
        level,
        floor_scale,
        frame,
    )


def _refit_leaders(
    problem: Problem, fit: ModelFit, candidates: list[Candidate], effects: tuple[str, ...]
) -> None:
    """Refit the :data:`N_LEADERS` best-scoring available, identifiable candidates."""
    ranked = sorted(candidates, key=lambda c: (not (c.available and c.identifiable), -c.score))
    for c in ranked[:N_LEADERS]:
        if not (c.available and c.identifiable):
            continue
        try:
            c.refit = fit_model(problem, (*effects, c.effect), seed_fit=fit)
        except (ValueError, np.linalg.LinAlgError) as exc:
            c.reason = f"refit failed: {exc}"
            continue
        c.delta_bic = bic_delta(problem, fit, c.refit) + _search_penalty(problem, fit, c.effect)


def _search_penalty(problem: Problem, fit: ModelFit, name: str) -> float:
    """ΔBIC's share of parameters an effect found by a search (``searched_params`` per
    column: the zero steps' times), beyond the columns of its linear fit."""
    per = float(getattr(get_effect(name), "searched_params", 0))
    if not per:
        return 0.0
    n = fit.refinement.dof + len(fit.refinement.x)  # the residual rows
    return float(per * len(get_effect(name).params(problem.design)) * np.log(n))


def _floor(
    problem: Problem,
    fit: ModelFit,
    effects: tuple[str, ...],
    candidates: list[Candidate],
    sig: NoiseSigmas | None,
    notes: list[str],
    made: ModelFit | None = None,
) -> tuple[np.ndarray, str, float, float]:
    """(floor (M, 6) mm, where it comes from, s², cap): the stated noise propagated through the
    model; without it, the noise level s (relative to a typical tracker and encoder) of the
    richest model these data allow, the floor capped (by the factor ``cap`` ≤ 1) at the best
    held-out residual of the models tried."""
    if sig is not None:
        floor = noise_floor(problem, fit)
        return floor, "stated instrument noise, propagated through the fitted model", 1.0, 1.0
    richest = tuple(effects) + tuple(c.effect for c in candidates if c.available and c.identifiable)
    if made is not None and made.effects == richest:
        rich = made  # the outlier search's richest fit on these poses
    else:
        try:
            rich = fit_model(problem, richest, cross_validate=False, seed_fit=fit)
        except (ValueError, np.linalg.LinAlgError):
            rich = fit
    s2 = rich.chi2 / rich.dof
    r = fit.refinement
    cov = leg_covariance(r.a, r.b, problem.meas.position, problem.R, DEFAULT_SIGMAS)
    floor = np.sqrt(s2 * np.einsum("mkk->mk", cov))
    source = (
        "estimated (no instruments file): the residual level of a fit with every identifiable "
        f"catalogue effect ({', '.join(richest)}); an effect outside the catalogue would inflate it"
    )
    heldout = [fit.cv_rms_mm] + [c.refit.cv_rms_mm for c in candidates if c.refit is not None]
    cap = floor_cap(float(np.sqrt(np.mean(floor**2))), heldout)
    if cap < 1.0:
        floor = cap * floor
        source += (
            f", capped at {1000 * min(heldout):.1f} µm, the best held-out residual of the models "
            "tried: the noise can leave no more than that"
        )
    notes.append(
        "the noise floor is estimated, not stated: pass --instruments for a firmer verdict"
    )
    return floor, source, float(s2), cap


def _weigh(
    problem: Problem,
    fit: ModelFit,
    candidates: list[Candidate],
    s2: float,
    excess: bool,
    band: float,
) -> None:
    """For every refitted candidate: the share of the excess it explains, its held-out gain,
    and (when the excess is significant) whether it brings the residual to the floor alone or
    with one more effect, or leaves only what the rest of the catalogue explains."""
    expected = fit.dof * s2
    chol = None
    for c in candidates:
        if c.refit is None:
            continue
        # A share of the excess only where there is one: at the floor the excess is noise and
        # the ratio of two small numbers (it read "explains 851 %").
        if excess and fit.chi2 > expected:
            c.explained = float((fit.chi2 - c.refit.chi2) / (fit.chi2 - expected))
        chol = pose_whiteners(problem, fit) if chol is None else chol
        c.heldout_dchi2, c.heldout_z = heldout_gain(fit, c.refit, chol, s2)
        if excess:
            c.closes, c.with_effect = _closes_excess(problem, c, candidates, s2, band)
            c.chain = c.closes or _catalogue_closes(problem, c, candidates, s2, band)


def _closes_excess(
    problem: Problem,
    c: Candidate,
    candidates: list[Candidate],
    expected_per_dof: float,
    band: float,
) -> tuple[bool, str]:
    """Does adding ``c`` bring the residual back to the noise floor — alone, or with one more
    catalogue effect (scored at ``c``'s refit)? An effect that leaves a significant excess only
    nibbles at a structured residual, unless another catalogue effect accounts for the rest
    (two hidden effects are then named one after the other)."""
    ref = c.refit
    if ref is None:
        raise ValueError(f"{c.effect} has not been refitted: nothing to test")
    if ref.chi2 / (ref.dof * expected_per_dof) <= band:
        return True, ""
    q = None
    for other in candidates:
        if other.effect == c.effect or not (other.available and other.identifiable):
            continue
        q = Projection.of(problem, ref) if q is None else q
        second = score_candidate(problem, ref, other.effect, q)
        if not second.identifiable:
            continue
        n_extra = len(get_effect(other.effect).params(problem.design))
        if (ref.chi2 - second.score) / ((ref.dof - n_extra) * expected_per_dof) <= band:
            return True, other.effect
    return False, ""


def _catalogue_closes(
    problem: Problem, c: Candidate, candidates: list[Candidate], s2: float, band: float
) -> bool:
    """Would the other available, identifiable catalogue effects together bring ``c``'s refit
    to the floor (to first order: their joint score at the refit)? Then the excess ``c``
    leaves is what more effects hiding at once explain, not a structure outside the
    catalogue."""
    ref = c.refit
    others = [o for o in candidates if o is not c and o.available and o.identifiable]
    if ref is None or not others:
        return False
    cols = np.concatenate([whitened_columns(ref, problem.basis(o.effect)) for o in others], 1)
    removed = block_score(ref, cols)
    dof = ref.dof - cols.shape[1]
    return bool(dof > 0 and (ref.chi2 - removed) / (dof * s2) <= band)


def _look_alike(problem: Problem, named: Candidate) -> list[str]:
    """What else leaves the residual the named effect explains (the effect's
    :meth:`~hexcal.effects.base.Effect.look_alike`, at its fitted values), as a note."""
    if named.refit is None:
        return []
    eff = get_effect(named.effect)
    names = [s.name for s in eff.params(problem.design)]
    fitted = {p.name: p.value for p in named.refit.params}
    text = eff.look_alike(np.array([fitted[n] for n in names]), problem.design)
    return [text] if text else []


def _named_notes(
    best: Candidate, alike: list[str], fit: ModelFit, candidates: list[Candidate], s2: float
) -> list[str]:
    """What the verdict leaves to say: what else the excess needs, and what fits alike."""
    out = []
    if best.with_effect:
        out.append(
            f"{best.effect} leaves an excess that {best.with_effect} would explain: "
            f"add {best.effect}, then diagnose again"
        )
    elif best.refit is not None and best.chain and not best.closes:
        out.append(
            f"{best.effect} explains {100 * best.explained:.0f} % of the excess and predicts "
            f"held-out poses better (held-out RMS {1000 * fit.cv_rms_mm:.2f} → "
            f"{1000 * best.cv_rms_mm_after:.2f} µm), but leaves an excess that several other "
            f"catalogue effects together account for: more than one effect hides here. Add "
            f"{best.effect}, then diagnose again (--auto goes on)"
        )
    if alike:
        rows = [c for c in candidates if c.effect in (best.effect, *alike) and c.refit]
        out.append(
            f"{' or '.join([best.effect, *alike])}: these poses cannot tell them apart ("
            + "; ".join(
                f"{c.effect}: χ² {c.refit.chi2 / s2:.1f}, ΔBIC {c.delta_bic:.0f}, held-out "
                f"{1000 * c.cv_rms_mm_after:.2f} µm"
                for c in rows
                if c.refit is not None
            )
            + f"). {best.effect} is taken first only because its ΔBIC is lowest, a margin "
            "inside the noise; record "
            + "; ".join(get_effect(e).separating_motion for e in [best.effect, *alike])
            + " to separate them"
        )
    return out


def _note_heldout_refusals(candidates: list[Candidate], notes: list[str]) -> None:
    """At the floor: effects with strong in-sample evidence that do not predict held-out poses
    better are not named; say so."""
    refused = [
        c
        for c in candidates
        if c.refit is not None and c.delta_bic < BIC_STRONG and not c.heldout_z > HELDOUT_Z
    ]
    if refused:
        notes.append(
            "at the noise floor, "
            + ", ".join(
                f"{c.effect} (ΔBIC {c.delta_bic:.0f}, held-out gain {c.heldout_z:.1f} σ)"
                for c in refused
            )
            + f" would fit better in-sample but predict held-out poses no better beyond "
            f"{HELDOUT_Z:g} σ: not named (a look-alike fitting the noise, or an effect too small "
            "to matter here)"
        )


def _robot_before_session(
    best: Candidate, candidates: list[Candidate], winners: list[Candidate], excess: bool, notes
) -> Candidate | None:
    """A property of the session (drift) is named only when the evidence prefers it to every
    effect of the robot that also brings the residual to the floor. A steady temperature rise
    follows the clock, and a uniform expansion of the legs lifts the platform like a vertical
    drift of the tracker: when the robot's own effect explains the residual as well, it is not
    blamed on the session (``best`` yields to the best winner of the robot, or to none)."""
    rivals = [
        c
        for c in candidates
        if c.refit is not None
        and not of_the_session(c.effect)
        and c.delta_bic < BIC_STRONG
        and (c.closes or not excess)
        and c.delta_bic <= best.delta_bic
    ]
    if not rivals:
        return best
    rival = min(rivals, key=lambda c: c.delta_bic)
    of_robot = [c for c in winners if not of_the_session(c.effect)]
    fallback = min(of_robot, key=lambda c: c.delta_bic) if of_robot else None
    notes.append(
        f"{best.effect} and {rival.effect} both bring the residual to the noise floor, and the "
        f"evidence prefers {rival.effect} (ΔBIC {rival.delta_bic:.0f} against "
        f"{best.delta_bic:.0f}), which explains only {100 * rival.explained:.0f} % of the "
        f"excess: with the temperature rising steadily over the session the two are hard to "
        f"tell apart, so {best.effect} is not named"
        + (
            f"; the verdict is {fallback.effect}, the robot's best effect that explains most of it"
            if fallback is not None
            else "; a session whose temperature changes unevenly (or holds) separates them"
        )
    )
    return fallback
