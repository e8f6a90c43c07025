"""The diagnosis in plain words, for the top of the report: what the robot has that its drawing
does not ("leg 3's encoder reads 0.2 % short"), and what that means for the platform ("with
that corrected, the platform is within 12 µm of where the controller believes it is"). The
statistics that back each sentence follow in the report; the glossary explains their terms.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from hexcal.diagnosis.diagnose import Diagnosis
from hexcal.effects import get_effect
from hexcal.effects.base import leg_of
from hexcal.estimate.effect_fit import ParamRow
from hexcal.vocabulary import Outcome

#: A parameter is told in words when its value is at least this many σ from zero.
SIGNIFICANT_SIGMAS = 3.0

#: Terms the report uses, in words.
GLOSSARY = {
    "held-out": "predicted by a fit that did not see the pose (cross-validation): the error a "
    "new pose would show, not how well the fit copies the poses it was given",
    "noise floor": "the error the tracker's and the encoders' own noise alone would leave: no "
    "model can do better, so a model at the floor misses nothing the data can show",
    "leg residual": "an encoder reading minus the reading the model predicts at the tracked pose",
    "RMS": "root mean square: the typical size of an error",
    "95 %": "the error 95 of 100 poses stay within",
    "Model 36 / Model 42": "the geometry alone (the 6 base and 6 platform joint centres, 36 "
    "numbers), and the geometry with each leg's length at zero reading (6 more)",
    "effect": "a physical behaviour beyond the geometry (encoder scale, backlash, thermal "
    "expansion, compliance...) that hexcal can add to the model",
    "χ²/dof": "the residual's size against the noise: about 1 when only noise is left",
    "ΔBIC": "how much better a model with the effect explains the data, after a penalty for "
    "its extra parameters; below −10 is strong evidence for the effect",
    "Δχ²": "how much the effect lowers the residual, measured in units of the noise",
    "explained": "the share of the residual above the noise floor that adding the effect removes",
    "identifiable": "whether these poses determine the parameter; when not, other motions are "
    "needed (each effect says which)",
    "outlier": "a pose whose readings disagree grossly with every model: a mis-recorded pose, "
    "a knock, a leg against its end stop",
}


def _significant(p: ParamRow) -> bool:
    return math.isfinite(p.sigma) and p.sigma > 0 and abs(p.value) >= SIGNIFICANT_SIGMAS * p.sigma


def _in_words(p: ParamRow) -> str | None:
    """One clause for a fitted effect parameter; None for the geometry and the offsets (the
    calibrated geometry is the result itself, not a finding)."""
    effect = p.name.split(".")[0]
    if effect == "gain":
        side = "short" if p.value > 0 else "long"
        return f"leg {leg_of(p.name)}'s encoder reads {abs(p.value) / 1e4:.2g} % {side}"
    if effect == "backlash":
        return f"leg {leg_of(p.name)} has {1000 * p.value:.3g} µm of play when it reverses"
    if effect == "thermal":
        return f"the legs grow {p.value:.3g} ppm per kelvin of the structure's temperature"
    if effect == "leadscrew":
        return f"leg {leg_of(p.name)}'s screw has a {1000 * abs(p.value):.3g} µm error per turn"
    if effect == "compliance":
        return f"the legs give under load ({p.name} = {p.value:.3g} {p.unit})"
    if effect == "zero_step":
        # A property of the session, not of the robot: said, so the operator checks the leg.
        return f"leg {leg_of(p.name)}'s encoder zero stepped by {p.value:.3g} µm during the session"
    if effect == "drift":
        return f"the tracker or the robot drifted during the session ({p.value:.3g} {p.unit})"
    return None


def found(d: Diagnosis) -> list[str]:
    """What the final model holds beyond the geometry, in words: one clause per parameter that
    is clearly not zero (≥ 3 σ), grouped by effect."""
    clauses, steps = [], 0
    for p in d.fit.params:
        words = _in_words(p) if _significant(p) else None
        if words:
            clauses.append(words)
            steps += p.name.startswith("zero_step.")
    if steps:  # once, after the last: what a step is and what to check
        last = max(i for i, c in enumerate(clauses) if "zero stepped" in c)
        clauses[last] += " (lost counts or a re-home: check " + (
            "that encoder)" if steps == 1 else "those encoders)"
        )
    return clauses


def _length(mm: float) -> str:
    """A length as it reads best: µm below 1 mm, else mm."""
    return f"{1000 * mm:.0f} µm" if abs(mm) < 1 else f"{mm:.2f} mm"


def _accuracy_sentence(diags: Sequence[Diagnosis]) -> str:
    last = diags[-1].accuracy
    drawing = diags[0].design_accuracy
    if last is None or not math.isfinite(last.position_p95_mm):
        return ""
    text = (
        f"With the calibrated model, the platform is within {_length(last.position_p95_mm)} "
        "of where the controller believes it is (95 % of poses the fit did not see; "
        f"{_length(last.position_rms_mm)} RMS)"
    )
    if drawing is not None and math.isfinite(drawing.position_p95_mm):
        text += f"; with the drawing it was {_length(drawing.position_p95_mm)}"
    return text + "."


def plain_summary(diags: Sequence[Diagnosis]) -> list[str]:
    """The report's opening: a few sentences without statistics (see module docstring)."""
    d = diags[-1]
    out = []
    clauses = found(d)
    if clauses:
        out.append(
            "The robot differs from its drawing beyond the geometry: " + "; ".join(clauses) + "."
        )
    # "else" only after something was found or added: a clean session had nothing missing.
    something = bool(clauses or len(diags) > 1 or any(e != "offset" for e in d.effects))
    if d.verdict == Outcome.NONE and d.floor_estimated:
        head = "Nothing else is missing" if something else "Nothing is missing"
        out.append(
            f"{head}: what remains is at the estimated noise floor "
            f"({1000 * d.fit.cv_rms_mm:.0f} µm per leg against an estimated floor of "
            f"{1000 * d.noise_floor_mm:.0f} µm; no instruments file)."
        )
    elif d.verdict == Outcome.NONE:
        head = (
            "Nothing else is missing: what remains is the instruments' own noise"
            if something
            else "Nothing is missing: the model is at the noise floor"
        )
        out.append(
            f"{head} ({1000 * d.fit.cv_rms_mm:.0f} µm per leg against a floor of "
            f"{1000 * d.noise_floor_mm:.0f} µm)."
        )
    elif d.verdict == Outcome.UNEXPLAINED:
        out.append(
            "Something no catalogue effect describes remains: the model misses the legs by "
            f"{1000 * d.fit.cv_rms_mm:.0f} µm where the noise alone gives "
            f"{1000 * d.noise_floor_mm:.0f} µm{' (estimated)' * d.floor_estimated}. "
            + str(d.where.get("summary", "")).capitalize()
        )
        lead = None if d.exploration is None else d.exploration.lead
        if lead is not None:
            out.append(
                f"It follows the {lead.covariate.label} ({100 * lead.share:.0f} % of the excess), "
                f"which points at {lead.points_at}."
            )
    elif d.verdict == Outcome.NOISE_UNDERSTATED:
        out.append(
            f"The model misses the legs by {1000 * d.fit.cv_rms_mm:.0f} µm where the stated noise "
            f"gives {1000 * d.noise_floor_mm:.0f} µm, evenly everywhere: the instruments look "
            f"about {d.noise_factor:.1f}× noisier than stated, rather than an effect missing."
        )
    elif d.verdict == Outcome.OUTLIERS:
        out.append(
            f"{len(d.outliers)} poses disagree grossly with every model (mis-recorded, knocked, "
            "or against an end stop): look at them before trusting the calibration."
        )
    else:
        effect = get_effect(d.verdict)
        c = d.candidate(d.verdict)
        gain = ""
        if c is not None and c.refit is not None:
            gain = (
                f" Adding it lowers the error per leg from {1000 * d.fit.cv_rms_mm:.0f} to "
                f"{1000 * c.cv_rms_mm_after:.0f} µm."
            )
        out.append(f"The model still lacks {effect.name}: {effect.physics}{gain}")
    accuracy = _accuracy_sentence(diags)
    if accuracy:
        out.append(accuracy)
    return [s.replace("..", ".") for s in out]
