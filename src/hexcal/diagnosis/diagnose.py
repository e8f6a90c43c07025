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

from dataclasses import dataclass, field

import numpy as np

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
from hexcal.diagnosis.score import Projection, column_norms, score_columns
from hexcal.diagnosis.where import concentrations
from hexcal.effects import CATALOGUE, get_effect
from hexcal.estimate.accuracy import PoseAccuracy, PoseErrors
from hexcal.estimate.effect_fit import (
    ModelFit,
    Problem,
    cross_validated,
    design_accuracy,
    design_pose_errors,
    fit_model,
    heldout_accuracy,
    heldout_pose_errors,
    noise_floor,
)
from hexcal.io.measurements import Measurements
from hexcal.model.instruments import Instruments
from hexcal.model.noise import DEFAULT_SIGMAS, NoiseSigmas, leg_covariance
from hexcal.model.robot import Robot
from hexcal.vocabulary import ModelKind, Outcome, Verdict

#: ΔBIC below which an effect's evidence is "very strong" (Kass & Raftery).
BIC_STRONG = -10.0
#: An effect must explain at least this share of the excess over the noise floor.
MOST = 0.5
#: Below this sine of the principal angle to the model's Jacobian, a parameter is absorbed
#: outright (a rank failure).
MIN_SINE = 1e-4
#: Otherwise it is separable when its standard error, once the model's parameters are projected
#: out (σ_alone / sin θ), resolves this fraction of its plausible range's half-width.
RESOLVE = 0.1
#: The residual exceeds the floor when χ²/dof is this many standard deviations of the χ²
#: distribution above 1. Over clean simulated sessions the fitted χ²/dof spreads 15 % wider
#: than theory (the whitening uses estimated geometry), hence 4 rather than 3.
EXCESS_Z = 4.0
#: How many leaders are refitted.
N_LEADERS = 3
#: The verdict when gross outliers are the whole story, and the name that, among the added
#: effects, acknowledges them (they stay set aside, no longer a verdict).
OUTLIERS = Outcome.OUTLIERS


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

    @property
    def cv_rms_mm_after(self) -> float:
        return self.refit.cv_rms_mm if self.refit is not None else float("nan")


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

    @property
    def effects(self) -> tuple[str, ...]:
        return self.fit.effects

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
            floor[rows] = np.sqrt(self.noise_level * np.einsum("mkk->mk", cov))
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
            "noise_floor_mm": self.noise_floor_mm,
            "noise_floor_source": self.floor_source,
            "chi2_per_dof": self.chi2_per_dof,
            "excess_significant": self.excess_significant,
            "verdict": self.verdict,
            "rms_per_leg_mm": f.rms_per_leg.tolist(),
            "cv_rms_per_leg_mm": f.cv_rms_per_leg.tolist(),
            "rms_per_step": f.rms_per_step(self.problem.meas.step),
            "candidates": [
                {
                    "effect": c.effect,
                    "score_dchi2": c.score,
                    "cv_rms_mm_after": _nan_none(c.cv_rms_mm_after),
                    "delta_bic": _nan_none(c.delta_bic),
                    "explained_fraction": _nan_none(c.explained),
                    "identifiable": c.identifiable,
                    "closes_excess": c.closes,
                    "available": c.available,
                    "reason": c.reason,
                    "absorbed_by": c.absorbed_by,
                    "separating_motion": c.separating_motion,
                    "nonphysical": [p.name for p in c.refit.nonphysical()] if c.refit else [],
                    "of_the_session": _of_the_session(c.effect),
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


def _of_the_session(name: str) -> bool:
    """A property of the session (the tracker drifting), not of the robot: such an effect is
    fitted to calibrate from this session but not carried into the calibrated model."""
    return bool(getattr(get_effect(name), "of_the_session", False))


def _nan_none(v: float) -> float | None:
    return None if not np.isfinite(v) else float(v)


def jacobian_basis(fit: ModelFit, problem: Problem | None = None) -> Projection | None:
    """What :func:`score_candidate` projects out: the fit's whitened Jacobian, as its normal
    equations (:class:`~hexcal.diagnosis.score.Projection`); made once per fit, when first
    asked for with the fit's ``problem``."""
    if problem is None:
        return fit.refinement.derived.get("projection")
    return Projection.of(problem, fit)


def score_candidate(
    problem: Problem, fit: ModelFit, name: str, q: Projection | None = None
) -> Candidate:
    """Score test and identifiability of one effect at the current fit (``q``: the fit's
    :func:`jacobian_basis`, when already made; it is made here otherwise)."""
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
    # What the data must resolve: the spec's own resolution, else a tenth of the half-width.
    need = np.array(
        [
            r if (r := getattr(sp, "resolution", None)) is not None else RESOLVE * h
            for sp, h in zip(specs, half, strict=True)
        ]
    )
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
            f"{np.nanmax(se[unresolved] / half[unresolved]):.2g} of the plausible range); "
            f"record {eff.separating_motion}"
        )
    return cand


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
        q = jacobian_basis(ref, problem) if q is None else q
        second = score_candidate(problem, ref, other.effect, q)
        if not second.identifiable:
            continue
        n_extra = len(get_effect(other.effect).params(problem.design))
        if (ref.chi2 - second.score) / ((ref.dof - n_extra) * expected_per_dof) <= band:
            return True, other.effect
    return False, ""


def _bic_delta(problem: Problem, base: ModelFit, new: ModelFit) -> float:
    n = base.refinement.dof + len(base.refinement.x)  # the residual rows
    dp = new.n_params - base.n_params
    if problem.sigmas is not None:
        return (new.chi2 - base.chi2) + dp * np.log(n)
    return n * np.log(new.chi2 / base.chi2) + dp * np.log(n)


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
    search = None
    if set_aside_outliers:
        start = None
        if isinstance(given, Subset):
            start = np.setdiff1d(np.arange(len(problem.meas)), given.rows)
        search = find_outliers(problem, effects, start)
        outliers, threshold, work = search.outliers, search.threshold, search.problem
        notes += search.notes
        if (
            isinstance(given, Subset)
            and isinstance(work, Subset)
            and np.array_equal(given.rows, work.rows)
        ):
            work = given  # the same poses: keep its cached bases and the drawing's accuracy
    verdict, fit, candidates, floor, floor_source, s2, excess, chi2_per_dof = _verdict(
        work, effects, sig, notes, search
    )
    if outliers:
        story = ""
        if verdict == Outcome.NONE:
            story = "without them the model is at the noise floor"
            if acknowledged:
                story += " (they were acknowledged: set aside, no longer a verdict)"
            elif _outliers_make_an_excess(problem, fit, outliers, s2):
                verdict = OUTLIERS
                story += ", with them far above it: they are the whole story"
            else:
                story += ", and with them it would still be: too few and too small to be a verdict"
        else:
            story = f"the verdict ({verdict}) is what the other poses say"
        notes.insert(0, _outlier_note(outliers, threshold, len(problem.meas), story))
    session_effects = [e for e in effects if _of_the_session(e)]
    if verdict in CATALOGUE and _of_the_session(verdict):
        session_effects.append(verdict)
    for e in session_effects:
        notes.append(
            f"{e} is a property of this session, not of the robot: it is fitted to calibrate from "
            "these poses, but a calibrated model does not carry it (another session drifts "
            "otherwise); let the tracker warm up, fix its stand, and record the session again to "
            "check"
        )
    where = concentrations(work, fit, floor)
    floor_sig = sig if sig is not None else _scaled(DEFAULT_SIGMAS, float(np.sqrt(s2)))
    errors = heldout_pose_errors(work, fit)
    accuracy = heldout_accuracy(work, fit, floor_sig, errors)
    if work.design_pose_accuracy is None:
        work.design_pose_accuracy = design_accuracy(work, floor_sig)
    candidates.sort(
        key=lambda c: (np.isnan(c.delta_bic), c.delta_bic if np.isfinite(c.delta_bic) else -c.score)
    )
    floor_mm = float(np.sqrt(np.mean(floor**2)))
    return Diagnosis(
        fit,
        floor_mm,
        floor_source,
        float(chi2_per_dof),
        bool(excess),
        verdict,
        candidates,
        where,
        floor,
        work,
        notes,
        accuracy,
        work.design_pose_accuracy,
        errors,
        design_pose_errors(work),
        outliers=outliers,
        outlier_threshold=threshold,
        outliers_acknowledged=acknowledged,
        noise_level=float(s2),
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


def _verdict(
    problem: Problem,
    effects: tuple[str, ...],
    sig: NoiseSigmas | None,
    notes: list,
    search: OutlierSearch | None = None,
):
    """Fit, score, refit the leaders and decide, on ``problem``'s poses: (verdict, fit,
    candidates, floor (M, 6), floor source, s² (noise level, 1 when stated), excess
    significant, χ²/dof over the floor). Notes are appended to ``notes``. The outlier
    ``search``'s fits on these poses are reused, not made again."""
    made = search.fit if search is not None else None
    if made is not None and made.effects == effects:
        fit = cross_validated(problem, made)
    else:
        fit, search = fit_model(problem, effects), None

    q = jacobian_basis(fit, problem)
    candidates = [score_candidate(problem, fit, n, q) for n in CATALOGUE if n not in effects]
    ranked = sorted(candidates, key=lambda c: (not (c.available and c.identifiable), -c.score))
    for c in ranked[:N_LEADERS]:
        if not (c.available and c.identifiable):
            continue
        try:
            c.refit = fit_model(problem, (*effects, c.effect), seed_fit=fit)
        except (ValueError, np.linalg.LinAlgError) as exc:
            c.reason = f"refit failed: {exc}"
            continue
        c.delta_bic = _bic_delta(problem, fit, c.refit)

    # The noise floor: the stated noise propagated through the model; without it, the noise
    # level s (relative to a typical tracker and encoder) of the richest model these data allow.
    if sig is not None:
        floor = noise_floor(problem, fit)
        floor_source = "stated instrument noise, propagated through the fitted model"
        s2 = 1.0
    else:
        richest = tuple(effects) + tuple(
            c.effect for c in candidates if c.available and c.identifiable
        )
        if search is not None and search.rich is not None and search.rich.effects == richest:
            rich = search.rich
        else:
            try:
                rich = fit_model(problem, richest, cross_validate=False, seed_fit=fit)
            except (ValueError, np.linalg.LinAlgError):
                rich = fit
        s2 = rich.chi2 / rich.dof
        r = fit.refinement
        cov = leg_covariance(r.a, r.b, problem.meas.position, problem.R, DEFAULT_SIGMAS)
        floor = np.sqrt(s2 * np.einsum("mkk->mk", cov))
        floor_source = (
            "estimated (no instruments file): the residual level of a fit with every identifiable "
            f"catalogue effect ({', '.join(richest)}); an effect outside the catalogue would inflate it"
        )
        notes.append(
            "the noise floor is estimated, not stated: pass --instruments for a firmer verdict"
        )
    expected = fit.dof * s2  # χ² the current fit would have from noise alone
    chi2_per_dof = fit.chi2 / expected
    excess = chi2_per_dof > 1.0 + EXCESS_Z * np.sqrt(2.0 / fit.dof)
    for c in candidates:
        if c.refit is not None and fit.chi2 > expected:
            c.explained = float((fit.chi2 - c.refit.chi2) / (fit.chi2 - expected))

    # "Explains most of the excess" only means something when there is a significant excess to
    # explain; below it, the excess is mostly noise and strong evidence (ΔBIC) decides alone.
    band = 1.0 + EXCESS_Z * np.sqrt(2.0 / fit.dof)
    for c in candidates:
        if c.refit is not None and excess:
            c.closes, c.with_effect = _closes_excess(
                problem, c, candidates, expected_per_dof=s2, band=band
            )
    winners = [
        c
        for c in candidates
        if c.refit is not None
        and c.delta_bic < BIC_STRONG
        and (not excess or (c.explained >= MOST and c.closes))
    ]
    best = min(winners, key=lambda c: c.delta_bic) if winners else None
    if best is not None and _of_the_session(best.effect):
        best = _robot_before_session(best, candidates, winners, excess, notes)
    verdict: Verdict
    if best is not None:
        verdict = best.effect
        if best.with_effect:
            notes.append(
                f"{best.effect} leaves an excess that {best.with_effect} would explain: "
                f"add {best.effect}, then diagnose again"
            )
    elif excess:
        verdict = Outcome.UNEXPLAINED
        helpful = [
            (c, c.refit) for c in candidates if c.refit is not None and c.delta_bic < BIC_STRONG
        ]
        if helpful:
            notes.append(
                "some effects help but none brings the residual to the noise floor, alone or with one more "
                "catalogue effect: "
                + ", ".join(
                    f"{c.effect} (explains {100 * c.explained:.0f} % of the excess, leaves χ²/dof "
                    f"{refit.chi2 / (refit.dof * s2):.2f})"
                    for c, refit in helpful
                )
            )
    else:
        verdict = Outcome.NONE
    return verdict, fit, candidates, floor, floor_source, s2, excess, chi2_per_dof


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
        and not _of_the_session(c.effect)
        and c.delta_bic < BIC_STRONG
        and (c.closes or not excess)
        and c.delta_bic <= best.delta_bic
    ]
    if not rivals:
        return best
    rival = min(rivals, key=lambda c: c.delta_bic)
    of_robot = [c for c in winners if not _of_the_session(c.effect)]
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


def _scaled(sig: NoiseSigmas, s: float) -> NoiseSigmas:
    return NoiseSigmas(s * sig.position_mm, s * sig.orientation_rad, s * sig.reading_mm)
