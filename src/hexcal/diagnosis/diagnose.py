"""The diagnosis: is the model at the noise floor, and if not, which effect is missing?

1. Fit the current model; its χ² against the stated noise says whether the residual exceeds the
   noise floor (excess significant at 4σ of the χ² distribution).
2. Every catalogue effect not in the model is scored at the current fit: the score (Lagrange
   multiplier) statistic, i.e. how much of the whitened residual its basis explains once the
   model's own parameters are projected out. Its identifiability is the principal angle between
   its basis and the model's Jacobian: an effect the current parameters can mimic is refused,
   with what absorbs it and the motion that would separate it.
3. The leaders are refitted for real: ΔBIC, the fraction of the excess χ² they explain, and the
   held-out RMS.
4. Verdict: the best identifiable effect with ΔBIC < −10 that — when the excess over the floor
   is significant — explains at least half of it; else ``unexplained`` when the excess is
   significant (with where it concentrates); else ``none``.
5. An effect named over a significant excess is challenged by the covariate explorer run on
   the model without it (:mod:`hexcal.diagnosis.challenge`): a shape outside the catalogue
   that predicts held-out poses better takes the verdict (``unexplained``, with that lead);
   one that predicts alike is named beside it.

Before all this, gross outliers — poses the richest identifiable model cannot explain
(:mod:`hexcal.diagnosis.outliers`) — are set aside, and everything above (the fit, the
cross-validation, the held-out RMS and pose accuracy, the candidates) is computed without
them. The verdict is then ``outliers`` when they are the whole story (without them the model is
at the noise floor), or what the rest of the poses say, with the outliers listed. Once the
outliers are acknowledged (``"outliers"`` among the added effects, as ``--add outliers`` or
``diagnose --auto`` after an ``outliers`` verdict) they are still set aside and listed, but no
longer a verdict: a session with a hidden backlash and three outliers reads ``backlash``
(outliers listed), then ``outliers`` once backlash is added, then ``none``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from hexcal.diagnosis.challenge import challenge
from hexcal.diagnosis.changepoint import ChangePoint
from hexcal.diagnosis.defaults import DefaultNote, default_notes
from hexcal.diagnosis.explorer import Exploration, explore
from hexcal.diagnosis.frame_search import FrameChange
from hexcal.diagnosis.locators import locate_effects
from hexcal.diagnosis.outliers import (
    OUTLIER_ALPHA,
    Outlier,
    OutlierSearch,
    Subset,
    find_outliers,
    pose_chi2,
    pose_residuals,
    session_problem,
)
from hexcal.diagnosis.plan_offer import Offer, offers
from hexcal.diagnosis.readmitted import check_readmitted
from hexcal.diagnosis.scoring import Candidate, jacobian_basis, score_candidate
from hexcal.diagnosis.selection import BIC_STRONG, MOST
from hexcal.diagnosis.verdict import (
    EXCESS_Z,
    Judgement,
    judge,
    of_the_session,
    scaled,
)
from hexcal.diagnosis.where import concentrations
from hexcal.effects import CATALOGUE, get_effect
from hexcal.estimate.accuracy import PoseAccuracy, PoseErrors
from hexcal.estimate.effect_fit import (
    ModelFit,
    Problem,
    design_accuracy,
    design_pose_errors,
    heldout_accuracy,
    heldout_pose_errors,
)
from hexcal.io.measurements import Measurements
from hexcal.model.instruments import Instruments
from hexcal.model.noise import DEFAULT_SIGMAS, NoiseSigmas, leg_covariance
from hexcal.model.robot import Robot
from hexcal.vocabulary import ModelKind, Outcome, Verdict

__all__ = [
    "BIC_STRONG",
    "EXCESS_Z",
    "MOST",
    "Candidate",
    "Diagnosis",
    "diagnose",
    "jacobian_basis",
    "score_candidate",
]

#: The verdict when gross outliers are the whole story, and the name that, among the added
#: effects, acknowledges them (they stay set aside, no longer a verdict).
OUTLIERS = Outcome.OUTLIERS
#: The effect whose times the change-point search locates.
ZERO_STEP = "zero_step"
#: ``noise_understated`` needs every catalogue effect to explain less than this share of the
#: excess (a stated noise 2× too low leaves a few per cent to any of them).
NOISE_SHARE = 0.1


@dataclass
class Diagnosis:
    """Result of :func:`diagnose` (mm throughout)."""

    fit: ModelFit
    noise_floor_mm: float
    floor_source: str
    chi2_per_dof: float
    excess_significant: bool
    verdict: Verdict  #: an Outcome, or the name of the missing catalogue effect
    candidates: list[Candidate]
    where: dict
    floor_per_residual: np.ndarray
    problem: Problem
    notes: list[str] = field(default_factory=list)
    #: Pose error on held-out poses (the random folds), with the floor the noise gives
    accuracy: PoseAccuracy | None = None
    #: Pose error of the drawing (robot.json as designed) on every pose
    design_accuracy: PoseAccuracy | None = None
    #: Per pose: the held-out pose errors of this model, and the drawing's
    pose_errors: PoseErrors | None = None
    design_pose_errors: PoseErrors | None = None
    #: Gross outliers set aside (rows of the session's table): the fit, the cross-validation,
    #: the pose accuracy and ``problem`` are on the other poses
    outliers: list[Outlier] = field(default_factory=list)
    #: χ² over a pose's six legs (over the noise level) beyond which it is an outlier
    outlier_threshold: float = float("nan")
    #: The outliers were acknowledged (``"outliers"`` among the added effects)
    outliers_acknowledged: bool = False
    #: s²: the noise level the floor is relative to (1 with the stated noise; without it, the
    #: richest model's χ²/dof against a typical tracker and encoder)
    noise_level: float = 1.0
    #: The factor (≤ 1) an estimated floor was capped by: at the best held-out residual
    floor_scale: float = 1.0
    #: Other effects that fit these data as well as the verdict's (named with it)
    alike: list[str] = field(default_factory=list)
    #: Changes of a leg's zero located by the change-point search (``zero_step``'s times)
    changes: list[ChangePoint] = field(default_factory=list)
    #: Where an unexplained residual points (the covariate explorer); None unless the verdict
    #: is ``unexplained`` or ``noise_understated``
    exploration: Exploration | None = None
    #: How many times too low the stated noise looks (``noise_understated``): √(χ²/dof)
    noise_factor: float = float("nan")
    #: A rigid move of the tracker located by the search (``frame_step``'s time)
    frame: FrameChange | None = None
    #: The plans offered where the poses cannot decide (:func:`hexcal.diagnosis.plan_offer.offers`)
    plans: list[Offer] = field(default_factory=list)
    #: Candidates whose score rests on a robot.json key left at its default
    defaults: list[DefaultNote] = field(default_factory=list)
    #: mm, the chain's step before refitted on this step's poses where the two set aside
    #: other outliers (:func:`hexcal.diagnosis.same_poses.compare_steps`); NaN otherwise
    cv_rms_before_mm: float = float("nan")

    def default_note(self, effect: str) -> DefaultNote | None:
        return next((n for n in self.defaults if n.effect == effect), None)

    @property
    def effects(self) -> tuple[str, ...]:
        return self.fit.effects

    @property
    def floor_estimated(self) -> bool:
        """The floor is estimated from the residual (no instruments' noise was stated)."""
        return self.problem.sigmas is None

    def score_shown(self, c: Candidate) -> float:
        """A candidate's score Δχ² on the scale of its ΔBIC: over the noise level s² (1 with
        the stated noise; the estimated level otherwise)."""
        return float(c.score / self.noise_level)

    @property
    def model_name(self) -> str:
        """The fit's model name, with the outliers said when they were acknowledged and set
        aside (``Model 42 + backlash, 3 outliers set aside``)."""
        name = self.fit.model_name
        if self.outliers and self.outliers_acknowledged:
            name += f", {len(self.outliers)} outlier{'s' * (len(self.outliers) > 1)} set aside"
        return name

    @property
    def session_problem(self) -> Problem:
        """The problem over every pose of the session (``problem`` holds the poses kept)."""
        return session_problem(self.problem)

    @property
    def outlier_ids(self) -> list[int]:
        """The pose ids set aside as gross outliers."""
        return [o.pose_id for o in self.outliers]

    def candidate(self, name: str) -> Candidate | None:
        return next((c for c in self.candidates if c.effect == name), None)

    def residual_table(self) -> str:
        """CSV text: for every pose of the session and leg, the measured and predicted reading
        (mm), the residual, the held-out residual (random folds) and the noise floor, µm; and
        whether the pose was set aside as an outlier (1: not fitted, so its residual is
        held-out too)."""
        f = self.fit
        session = self.session_problem
        m = session.meas
        res, held, floor = f.residuals, f.held_out_residuals, self.floor_per_residual
        aside = np.zeros(len(m), bool)
        if self.outliers:
            rows = np.array([o.index for o in self.outliers])
            aside[rows] = True
            res, held, floor = (np.zeros((len(m), 6)) for _ in range(3))
            kept = ~aside
            res[kept], held[kept], floor[kept] = (
                f.residuals,
                f.held_out_residuals,
                self.floor_per_residual,
            )
            res[rows] = held[rows] = pose_residuals(session, f)[rows]
            r = f.refinement
            sig = session.sigmas if session.sigmas is not None else DEFAULT_SIGMAS
            cov = leg_covariance(r.a, r.b, m.position[rows], session.R[rows], sig)
            level = self.noise_level * self.floor_scale**2
            floor[rows] = np.sqrt(level * np.einsum("mkk->mk", cov))
        lines = [
            "pose_id,step,leg,measured_mm,predicted_mm,residual_um,heldout_residual_um,floor_um,"
            "set_aside"
        ]
        for i in range(len(m)):
            for k in range(6):
                lines.append(
                    f"{m.pose_id[i]},{m.step[i]},{k + 1},{float(m.readings[i, k])!r},{float(m.readings[i, k] - res[i, k])!r},"
                    f"{1000 * res[i, k]:.4f},{1000 * held[i, k]:.4f},{1000 * floor[i, k]:.4f},{int(aside[i])}"
                )
        return "\n".join(lines) + "\n"

    def to_dict(self) -> dict:
        """The JSON contract of ``hexcal diagnose --json``."""
        f = self.fit
        return {
            "model": f.model_name,
            "effects": list(f.effects),
            "rms_mm": f.rms_mm,
            "cv_rms_mm": f.cv_rms_mm,
            "cv_blocked_rms_mm": f.cv_blocked_rms_mm,
            "cv_rms_before_same_poses_mm": _nan_none(self.cv_rms_before_mm),
            "noise_floor_mm": self.noise_floor_mm,
            "noise_floor_source": self.floor_source,
            "noise_floor_estimated": self.floor_estimated,
            "chi2_per_dof": self.chi2_per_dof,
            "excess_significant": self.excess_significant,
            "verdict": self.verdict,
            "alike": list(self.alike),
            "plans": [p.to_dict() for p in self.plans],
            "noise_factor": _nan_none(self.noise_factor),
            "changes": [c.to_dict() for c in self.changes],
            "frame_change": None if self.frame is None else self.frame.to_dict(),
            "explore": None if self.exploration is None else self.exploration.to_dict(),
            "rms_per_leg_mm": f.rms_per_leg.tolist(),
            "cv_rms_per_leg_mm": f.cv_rms_per_leg.tolist(),
            "rms_per_step": f.rms_per_step(self.problem.meas.step),
            "candidates": [
                {
                    "effect": c.effect,
                    "score_dchi2": self.score_shown(c),
                    "cv_rms_mm_after": _nan_none(c.cv_rms_mm_after),
                    "delta_bic": _nan_none(c.delta_bic),
                    "explained_fraction": _nan_none(c.explained),
                    "identifiable": c.identifiable,
                    "closes_excess": c.closes,
                    "explained_with_others": c.chain,
                    "heldout_dchi2": _nan_none(c.heldout_dchi2),
                    "heldout_z": _nan_none(c.heldout_z),
                    "available": c.available,
                    "reason": c.reason,
                    "absorbed_by": c.absorbed_by,
                    "separating_motion": c.separating_motion,
                    "nonphysical": [p.name for p in c.refit.nonphysical()] if c.refit else [],
                    "of_the_session": of_the_session(c.effect),
                    "source": get_effect(c.effect).source.text(),
                    "default_key": (
                        None if (n := self.default_note(c.effect)) is None else n.to_dict()
                    ),
                }
                for c in self.candidates
            ],
            "where": self.where,
            "parameters": [
                {
                    "name": p.name,
                    "value": p.value,
                    "sigma": _nan_none(p.sigma),
                    "ci95": _nan_none(p.ci95),
                    "unit": p.unit,
                    "status": p.status,
                    "physical": p.physical,
                }
                for p in f.params
            ],
            "outliers": [o.to_dict() for o in self.outliers],
            "outlier_threshold_chi2": _nan_none(self.outlier_threshold),
            "outliers_acknowledged": self.outliers_acknowledged,
            "poses_used": len(self.problem.meas),
            "pose_accuracy": None if self.accuracy is None else self.accuracy.to_dict(),
            "design_pose_accuracy": (
                None if self.design_accuracy is None else self.design_accuracy.to_dict()
            ),
            "notes": self.notes + f.notes,
        }


def _nan_none(v: float) -> float | None:
    return None if not np.isfinite(v) else float(v)


def diagnose(
    meas: Measurements,
    design: Robot,
    model: ModelKind = ModelKind.M42,
    add: list[str] | tuple[str, ...] = (),
    instruments: Instruments | None = None,
    problem: Problem | None = None,
    *,
    set_aside_outliers: bool = True,
) -> Diagnosis:
    """Fit Model ``model`` plus the effects in ``add`` and diagnose what is missing.

    Gross outliers are set aside first (``set_aside_outliers``; see the module docstring):
    the returned diagnosis is computed on the other poses, and lists them. ``"outliers"`` in
    ``add`` acknowledges them: still set aside, no longer the verdict. ``problem``: an earlier
    diagnosis' (its session's precomputed arrays are reused, and its outliers tested first).
    """
    sig = NoiseSigmas.from_instruments(instruments) if instruments is not None else None
    given = problem
    problem = session_problem(problem) if problem is not None else Problem.build(meas, design, sig)
    acknowledged = OUTLIERS in add
    add = [e for e in add if e != OUTLIERS]
    effects = (("offset",) if model == ModelKind.M42 else ()) + tuple(
        e for e in add if not (e == "offset" and model == ModelKind.M42)
    )
    notes: list[str] = []
    outliers: list[Outlier] = []
    threshold = float("nan")
    work = problem
    search: OutlierSearch | None = None
    locate_effects(problem, effects)  # zero_step's steps, found as calibrate finds them
    if set_aside_outliers:
        outliers, threshold, work, search = _set_aside(problem, given, effects, notes)
    j = judge(work, effects, sig, notes, outliers=search)
    fit, verdict = j.fit, j.verdict
    if outliers:
        verdict = _outlier_story(problem, j, outliers, threshold, acknowledged, notes)
    _session_notes(effects, verdict, notes)
    where = concentrations(
        work,
        fit,
        j.floor,
        excess=j.excess,
        outliers=outliers,
        changes=j.changes if verdict == ZERO_STEP else (),
    )
    noise_factor = float("nan")
    verdict, exploration, alike = _challenged(work, j, verdict, notes)
    if verdict == Outcome.UNEXPLAINED:
        if exploration is None:
            exploration = explore(work, fit, j.s2, max(j.level, j.s2))
        if outliers:  # its file would judge them again: a lead must hold on the poses it keeps
            check_readmitted(problem, work, fit.effects, exploration)
        if _noise_understated(j, where, exploration, sig is not None):
            verdict, noise_factor = Outcome.NOISE_UNDERSTATED, float(np.sqrt(j.chi2_per_dof))
            notes.append(_noise_note(noise_factor, j))
    floor_sig = sig
    if sig is None:  # the estimated level, capped as the leg-length floor was
        floor_sig = scaled(DEFAULT_SIGMAS, float(np.sqrt(j.s2)) * j.floor_scale)
    errors = heldout_pose_errors(work, fit)
    accuracy = heldout_accuracy(work, fit, floor_sig, errors)
    if work.design_pose_accuracy is None:
        work.design_pose_accuracy = design_accuracy(work, floor_sig)
    if sig is None:
        accuracy = replace(accuracy, floor_estimated=True)
        work.design_pose_accuracy = replace(work.design_pose_accuracy, floor_estimated=True)
    candidates = _by_evidence(j.candidates)
    return Diagnosis(
        fit,
        float(np.sqrt(np.mean(j.floor**2))),
        j.floor_source,
        j.chi2_per_dof,
        j.excess,
        verdict,
        candidates,
        where,
        j.floor,
        work,
        notes,
        accuracy,
        work.design_pose_accuracy,
        errors,
        design_pose_errors(work),
        outliers=outliers,
        outlier_threshold=threshold,
        outliers_acknowledged=acknowledged,
        noise_level=j.s2,
        floor_scale=j.floor_scale,
        alike=alike,
        changes=j.changes,
        exploration=exploration,
        noise_factor=noise_factor,
        frame=j.frame,
        defaults=default_notes(work, fit, j.candidates),
        plans=offers(work, fit, str(verdict), alike, j.candidates),
    )


def _by_evidence(candidates: list[Candidate]) -> list[Candidate]:
    """The refitted candidates by ΔBIC, then the others by score."""
    return sorted(
        candidates,
        key=lambda c: (
            np.isnan(c.delta_bic),
            c.delta_bic if np.isfinite(c.delta_bic) else -c.score,
        ),
    )


def _challenged(
    work: Problem, j: Judgement, verdict: Verdict, notes: list[str]
) -> tuple[Verdict, Exploration | None, list[str]]:
    """(the verdict, the exploration that overturned it if one did, the verdict's look-alikes):
    the explorer's lead against a catalogue effect named over a significant excess
    (:mod:`hexcal.diagnosis.challenge`), what it found said in ``notes``. Not where nothing
    is named, or what is named is a property of the session (a located step, the tracker's
    drift), or the excess is noise. Look-alikes are of an effect named: none once the lead
    has overturned it."""
    if isinstance(verdict, Outcome) or not j.excess or of_the_session(str(verdict)):
        return verdict, None, j.alike
    named = next((c for c in j.candidates if c.effect == verdict), None)
    found = None if named is None else challenge(work, j.fit, named, j.s2, max(j.level, j.s2))
    if found is None:
        return verdict, None, j.alike
    if text := found.note():
        notes.append(text)
    if found.overturns:
        return Outcome.UNEXPLAINED, found.exploration, []
    return verdict, None, j.alike


def _noise_understated(j: Judgement, where: dict, exploration: Exploration, stated: bool) -> bool:
    """An excess over the stated noise that nothing structures: no group of poses stands out
    from the rest, no leg's zero changed, no covariate leads and no catalogue effect explains a
    share of it worth naming (a leg's zero step among them) — the noise is larger than
    stated."""
    if not (stated and j.excess and where.get("even")) or exploration.leads:
        return False
    return not any(
        c.refit is not None and c.delta_bic < BIC_STRONG and c.explained >= NOISE_SHARE
        for c in j.candidates
    )


def _noise_note(factor: float, j: Judgement) -> str:
    return (
        f"the residual is {factor:.2f}× the stated noise (χ²/dof {j.chi2_per_dof:.2f}) and "
        "spread evenly: over the legs, the procedure's steps, time, the workspace and every "
        "covariate, and no catalogue effect explains a share of it. The stated noise looks "
        f"about {factor:.1f}× too low: measure the tracker's and the encoders' noise again "
        "(the scatter of still poses), correct instruments.json, and diagnose again"
    )


def _set_aside(
    problem: Problem, given: Problem | None, effects: tuple[str, ...], notes: list[str]
) -> tuple[list[Outlier], float, Problem, OutlierSearch]:
    """The gross outliers of the session ``problem`` (an earlier diagnosis' ``given`` tested
    first): (outliers, their χ² threshold, the problem on the poses kept, the search, whose
    fits the verdict reuses)."""
    start = None
    if isinstance(given, Subset):
        start = np.setdiff1d(np.arange(len(problem.meas)), given.rows)
    search = find_outliers(problem, effects, start)
    notes += search.notes
    work = search.problem
    if (
        isinstance(given, Subset)
        and isinstance(work, Subset)
        and np.array_equal(given.rows, work.rows)
    ):
        work = given  # the same poses: keep its cached bases and the drawing's accuracy
    return search.outliers, search.threshold, work, search


def _outlier_story(
    session: Problem,
    j: Judgement,
    outliers: list[Outlier],
    threshold: float,
    acknowledged: bool,
    notes: list[str],
) -> Verdict:
    """The verdict once outliers were set aside (``outliers`` when they are the whole story),
    with the note that says so first among ``notes``."""
    verdict = j.verdict
    if verdict == Outcome.NONE:
        story = "without them the model is at the noise floor"
        if acknowledged:
            story += " (they were acknowledged: set aside, no longer a verdict)"
        elif _outliers_make_an_excess(session, j.fit, outliers, j.s2):
            verdict = OUTLIERS
            story += ", with them far above it: they are the whole story"
        else:
            story += ", and with them it would still be: too few and too small to be a verdict"
    else:
        story = f"the verdict ({verdict}) is what the other poses say"
    notes.insert(0, _outlier_note(outliers, threshold, len(session.meas), story))
    return verdict


def _session_notes(effects: tuple[str, ...], verdict: Verdict, notes: list[str]) -> None:
    """The note of each effect of the session (fitted, not shipped) in the model or named."""
    session_effects = [e for e in effects if of_the_session(e)]
    if verdict in CATALOGUE and of_the_session(verdict):
        session_effects.append(verdict)
    for e in dict.fromkeys(session_effects):
        if e == "frame_step":
            notes.append(
                "frame_step is a property of this session, not of the robot: the tracker (or the "
                "robot's base) moved during it, and the move is fitted to calibrate from these "
                "poses, but the calibrated model does not carry it; fix the tracker's stand, and "
                "record the session again to check"
            )
            continue
        if e == ZERO_STEP:
            notes.append(
                "zero_step is a property of this session, not of the robot: the step is fitted "
                "to calibrate from these poses, but the calibrated model keeps each leg's zero as "
                "the session started (the robot as homed) and records the step's time "
                "(zero_steps); re-home before using it, and check the stepping leg's encoder "
                "(its cable, its index pulse) and whether it was re-homed mid-session"
            )
            continue
        notes.append(
            f"{e} is a property of this session, not of the robot: it is fitted to calibrate from "
            "these poses, but a calibrated model does not carry it (another session drifts "
            "otherwise); let the tracker warm up, fix its stand, and record the session again to "
            "check"
        )


def _outlier_note(outliers: list[Outlier], threshold: float, m: int, story: str) -> str:
    shown = "; ".join(o.text() for o in outliers[:10])
    more = f"; … and {len(outliers) - 10} more" if len(outliers) > 10 else ""
    ids = " ".join(str(o.pose_id) for o in outliers)
    return (
        f"{len(outliers)} of {m} poses are outliers, inconsistent with every model the "
        f"catalogue allows (χ² of their six legs beyond {threshold:.1f}, the "
        f"{100 * OUTLIER_ALPHA:g} % threshold over the session): {shown}{more}. They are set "
        f"aside — the fit, the held-out RMS and the pose accuracy are computed without them; the "
        f"table keeps them — and {story}. A bumped tracker or a pose taken mid-move: check, "
        f"re-measure, or leave them out with --exclude-poses {ids}"
    )


def _outliers_make_an_excess(
    session: Problem, fit: ModelFit, outliers: list[Outlier], s2: float
) -> bool:
    """Would the model fitted without the outliers exceed the noise floor (the same 4σ test)
    with their χ² at that fit counted in? Only then are they a verdict: one pose at the edge
    of a backlash dead band, a few σ out, is set aside and listed but is no story."""
    rows = [o.index for o in outliers]
    chi2 = fit.chi2 + float(pose_chi2(session, fit)[rows].sum())
    dof = fit.dof + 6 * len(rows)
    return chi2 / (dof * s2) > 1.0 + EXCESS_Z * np.sqrt(2.0 / dof)
