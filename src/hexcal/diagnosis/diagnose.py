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
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hexcal.accuracy import PoseAccuracy, PoseErrors
from hexcal.diagnosis.model import (
    ModelFit,
    Problem,
    design_accuracy,
    design_pose_errors,
    fit_model,
    heldout_accuracy,
    heldout_pose_errors,
    noise_floor,
)
from hexcal.diagnosis.where import concentrations
from hexcal.effects import CATALOGUE, get_effect
from hexcal.instruments import Instruments
from hexcal.measurements import Measurements
from hexcal.noise import DEFAULT_SIGMAS, NoiseSigmas, leg_covariance
from hexcal.robot import Robot

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
    verdict: str
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

    @property
    def effects(self) -> tuple[str, ...]:
        return self.fit.effects

    def candidate(self, name: str) -> Candidate | None:
        return next((c for c in self.candidates if c.effect == name), None)

    def residual_table(self) -> str:
        """CSV text: for every pose and leg, the measured and predicted reading (mm), the
        residual, the held-out residual (random folds) and the noise floor, µm."""
        m = self.problem.meas
        f = self.fit
        rows = [
            "pose_id,step,leg,measured_mm,predicted_mm,residual_um,heldout_residual_um,floor_um"
        ]
        for i in range(len(m)):
            for k in range(6):
                rows.append(
                    f"{m.pose_id[i]},{m.step[i]},{k + 1},{float(m.readings[i, k])!r},{float(m.readings[i, k] - f.residuals[i, k])!r},"
                    f"{1000 * f.residuals[i, k]:.4f},{1000 * f.cv_residuals[i, k]:.4f},{1000 * self.floor_per_residual[i, k]:.4f}"
                )
        return "\n".join(rows) + "\n"

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
            "pose_accuracy": None if self.accuracy is None else self.accuracy.to_dict(),
            "design_pose_accuracy": (
                None if self.design_accuracy is None else self.design_accuracy.to_dict()
            ),
            "notes": self.notes + f.notes,
        }


def _nan_none(v: float) -> float | None:
    return None if not np.isfinite(v) else float(v)


def _orthonormal(a: np.ndarray) -> np.ndarray:
    q, r = np.linalg.qr(a)
    keep = np.abs(np.diag(r)) > 1e-10 * max(np.abs(np.diag(r)).max(), 1e-300)
    return q[:, keep]


def score_candidate(problem: Problem, fit: ModelFit, name: str) -> Candidate:
    """Score test and identifiability of one effect at the current fit."""
    eff = get_effect(name)
    why = problem.missing(name)
    if why:
        return Candidate(
            name, 0.0, False, False, reason=why, separating_motion=eff.separating_motion
        )
    ref = fit.refinement
    W = ref.whiteners
    specs = eff.params(problem.design)
    names = [s.name for s in specs]
    basis = problem.basis(name)
    bw = np.einsum("mij,mjp->mip", W, -basis).reshape(-1, basis.shape[-1])
    jw = ref.whitened_jacobian
    q = _orthonormal(jw)
    b_perp = bw - q @ (q.T @ bw)
    norms = np.linalg.norm(bw, axis=0)
    sines = np.linalg.norm(b_perp, axis=0) / np.where(norms > 0, norms, 1.0)
    # Standard errors of the effect's parameters once the model's own are projected out.
    with np.errstate(divide="ignore", invalid="ignore"):
        se = np.sqrt(np.diag(np.linalg.pinv(b_perp.T @ b_perp)))
    half = np.array([(sp.plausible[1] - sp.plausible[0]) / 2 for sp in specs])
    unresolved = (sines < MIN_SINE) | ~(se < RESOLVE * half)
    absorbed = [names[i] for i in np.where(unresolved)[0]]
    r = ref.whitened_residual
    qb = _orthonormal(b_perp[:, ~unresolved]) if (~unresolved).any() else np.zeros((len(r), 0))
    score = float(np.sum((qb.T @ r) ** 2))
    cand = Candidate(
        name,
        score,
        identifiable=not absorbed,
        available=True,
        separating_motion=eff.separating_motion,
    )
    if absorbed:
        # Name the model parameters that mimic the worst-absorbed column.
        worst = int(np.argmin(sines))
        coef, *_ = np.linalg.lstsq(jw, bw[:, worst], rcond=None)
        share = np.abs(coef) * np.linalg.norm(jw, axis=0)
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
    if ref.chi2 / (ref.dof * expected_per_dof) <= band:
        return True, ""
    for other in candidates:
        if other.effect == c.effect or not (other.available and other.identifiable):
            continue
        second = score_candidate(problem, ref, other.effect)
        if not second.identifiable:
            continue
        n_extra = len(get_effect(other.effect).params(problem.design))
        if (ref.chi2 - second.score) / ((ref.dof - n_extra) * expected_per_dof) <= band:
            return True, other.effect
    return False, ""


def _bic_delta(problem: Problem, base: ModelFit, new: ModelFit) -> float:
    n = base.refinement.whitened_residual.size
    dp = new.n_params - base.n_params
    if problem.sigmas is not None:
        return (new.chi2 - base.chi2) + dp * np.log(n)
    return n * np.log(new.chi2 / base.chi2) + dp * np.log(n)


def diagnose(
    meas: Measurements,
    design: Robot,
    model: int = 42,
    add: list[str] | tuple[str, ...] = (),
    instruments: Instruments | None = None,
    problem: Problem | None = None,
) -> Diagnosis:
    """Fit Model ``model`` plus the effects in ``add`` and diagnose what is missing."""
    sig = NoiseSigmas.from_instruments(instruments) if instruments is not None else None
    problem = problem or Problem.build(meas, design, sig)
    effects = (("offset",) if model == 42 else ()) + tuple(
        e for e in add if not (e == "offset" and model == 42)
    )
    fit = fit_model(problem, effects)
    notes: list[str] = []

    candidates = [score_candidate(problem, fit, n) for n in CATALOGUE if n not in effects]
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

    floor_mm = float(np.sqrt(np.mean(floor**2)))
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
    if winners:
        best = min(winners, key=lambda c: c.delta_bic)
        verdict = best.effect
        if best.with_effect:
            notes.append(
                f"{best.effect} leaves an excess that {best.with_effect} would explain: "
                f"add {best.effect}, then diagnose again"
            )
    elif excess:
        verdict = "unexplained"
        helpful = [c for c in candidates if c.refit is not None and c.delta_bic < BIC_STRONG]
        if helpful:
            notes.append(
                "some effects help but none brings the residual to the noise floor, alone or with one more "
                "catalogue effect: "
                + ", ".join(
                    f"{c.effect} (explains {100 * c.explained:.0f} % of the excess, leaves χ²/dof "
                    f"{c.refit.chi2 / (c.refit.dof * s2):.2f})"
                    for c in helpful
                )
            )
    else:
        verdict = "none"
    where = concentrations(problem, fit, floor)
    floor_sig = sig if sig is not None else _scaled(DEFAULT_SIGMAS, float(np.sqrt(s2)))
    errors = heldout_pose_errors(problem, fit)
    accuracy = heldout_accuracy(problem, fit, floor_sig, errors)
    if problem.design_pose_accuracy is None:
        problem.design_pose_accuracy = design_accuracy(problem, floor_sig)
    candidates.sort(
        key=lambda c: (np.isnan(c.delta_bic), c.delta_bic if np.isfinite(c.delta_bic) else -c.score)
    )
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
        problem,
        notes,
        accuracy,
        problem.design_pose_accuracy,
        errors,
        design_pose_errors(problem),
    )


def _scaled(sig: NoiseSigmas, s: float) -> NoiseSigmas:
    return NoiseSigmas(s * sig.position_mm, s * sig.orientation_rad, s * sig.reading_mm)
