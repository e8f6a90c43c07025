"""Plain-text rendering of a diagnosis for the terminal."""

from __future__ import annotations

import textwrap

from hexcal.diagnosis.diagnose import Diagnosis
from hexcal.estimate.accuracy import floor_words
from hexcal.vocabulary import Outcome

#: What the ranked table's columns mean (the terminal's table and the report's say the same).
RANKED_LEGEND = (
    "score Δχ²: the χ² the effect would remove, to first order (the score test, before any "
    "refit); ΔBIC: the refit's evidence after a penalty for its parameters, below −10 very "
    "strong; explains: the share of the excess over the noise floor the refit removes (the "
    "verdict needs at least half); held-out after: the refit's held-out RMS; —: scored, not "
    "refitted (only the top three are), or no excess to explain"
)


def _floor(d: Diagnosis) -> str:
    return "noise floor" if not d.floor_estimated else "estimated noise floor"


def _um(x: float) -> str:
    return f"{1000 * x:6.2f}"


def diagnosis_text(
    d: Diagnosis, source: str, add: str = "--add {}", plan_command: str = "hexcal plan SESSION"
) -> str:
    """The diagnosis for a terminal; ``add``: how its reader adds an effect, ``{}`` the effect's
    name (the command line's option, or the text UI's key); ``plan_command``: ``hexcal plan``
    with the user's own arguments, for the plans offered (:attr:`Diagnosis.plans`)."""
    f = d.fit
    lines = [
        f"hexcal diagnose: {f.model_name} on {source}",
        f"{_floor(d)} {_um(d.noise_floor_mm)} µm — {d.floor_source}",
        f"residual RMS {_um(f.rms_mm)} µm in-sample, {_um(f.cv_rms_mm)} µm held-out (5-fold over poses), "
        f"{_um(f.cv_blocked_rms_mm)} µm held-out (folds blocked in time); χ²/dof {d.chi2_per_dof:.3f}"
        + (
            f" — above the {_floor(d)}"
            if d.excess_significant
            else f" — consistent with the {_floor(d)}"
        ),
        *_accuracy_lines(d),
        "",
        "per leg, µm:     " + "".join(f"{f'leg {k + 1}':>9}" for k in range(6)),
        "  in-sample RMS  " + "".join(f"{1000 * v:9.2f}" for v in f.rms_per_leg),
        "  held-out RMS   " + "".join(f"{1000 * v:9.2f}" for v in f.cv_rms_per_leg),
        "",
        "per procedure step, held-out RMS µm: "
        + ", ".join(
            f"{k} {1000 * v['cv_rms_mm']:.1f}"
            for k, v in f.rms_per_step(d.problem.meas.step).items()
        ),
        "",
        f"where: {d.where['summary']}",
        "worst poses: "
        + ", ".join(
            f"#{p['pose_id']} ({p['step']}, leg {p['worst_leg']}, {p['excess_ratio']:.1f}×)"
            for p in d.where["worst_poses"][:3]
        ),
        "",
        "missing effects, ranked:",
        f"  {'effect':<12}{'score Δχ²':>11}{'ΔBIC':>10}{'explains':>10}{'held-out after':>16}  identifiable",
    ]
    for c in d.candidates:
        bic = f"{c.delta_bic:10.1f}" if c.refit else f"{'—':>10}"
        expl = (
            f"{100 * c.explained:9.0f}%" if c.refit and c.explained == c.explained else f"{'—':>10}"
        )
        after = f"{_um(c.cv_rms_mm_after)} µm" if c.refit else "—"
        ident = "yes" if c.identifiable else ("n/a: " + c.reason if not c.available else "no")
        lines.append(f"  {c.effect:<12}{d.score_shown(c):11.1f}{bic}{expl}{after:>16}  {ident}")
        if c.available and not c.identifiable:
            lines.append(f"      {c.reason}")
        if (note := d.default_note(c.effect)) is not None:
            lines.append(f"      {note.text()}")
    if d.candidates:
        lines += textwrap.wrap(
            RANKED_LEGEND, 96, initial_indent="  legend: ", subsequent_indent="    "
        )
    if getattr(d, "outliers", None):
        lines.append("")
        lines.append(
            f"set aside as gross outliers ({len(d.outliers)}; the fit above is on the other poses): "
            + ", ".join(f"#{o.pose_id} ({o.step}, t {o.t:g} s)" for o in d.outliers[:10])
        )
    lines.append("")
    lines += verdict_lines(d, add)
    lines += plan_lines(d, plan_command)
    bad = f.nonphysical()
    notes = d.notes + f.notes
    if notes:
        lines.append("")
        lines.append("notes:")
        lines += [f"  - {n}" for n in notes]
    if bad:
        lines.append(
            "  (a value outside its plausible range is a flag, not a verdict: the note says what "
            "it means; set plausible in robot.json if this hardware allows it)"
        )
    return "\n".join(lines)


def verdict_lines(d: Diagnosis, add: str = "--add {}") -> list[str]:
    """The verdict in words, what it rests on, and what to do next."""
    f = d.fit
    v = d.verdict
    if v == Outcome.NONE:
        return [
            f"verdict: none — the residual is at the {_floor(d)}; nothing in the catalogue is "
            "missing"
        ]
    if v == Outcome.UNEXPLAINED:
        return [
            f"verdict: unexplained — the residual is above the {_floor(d)} but no catalogue "
            "effect explains most of it",
            f"  look at: {d.where['summary']}",
            *pointer_lines(d),
        ]
    if v == Outcome.NOISE_UNDERSTATED:
        return [
            f"verdict: noise_understated — the residual is {d.noise_factor:.2f}× the stated noise "
            "and spread evenly over legs, steps, time, the workspace and every covariate: the "
            f"stated noise looks about {d.noise_factor:.1f}× too low (check instruments.json)"
        ]
    if v == Outcome.OUTLIERS:
        return [
            f"verdict: outliers — {len(d.outliers)} poses no model explains (a bumped tracker, a "
            "pose taken mid-move); without them the model is at the noise floor. They stay in the "
            f"session, set aside: {add.format('outliers')} acknowledges them"
        ]
    won = d.candidate(v)
    if won is None:
        raise ValueError(f"the verdict {v!r} is none of the scored candidates")
    from hexcal.effects import get_effect

    alike = f" (or {' or '.join(d.alike)}: they fit alike, see the notes)" if d.alike else ""
    # No share when the residual is already at or below the estimated floor ("nan %" was said).
    share = (
        f"it explains {100 * won.explained:.0f} % of the excess over the noise floor"
        if won.explained == won.explained
        else "the residual is already at the noise floor, and it lowers it"
    )
    out = [
        f"verdict: {v}{alike} — {share} (ΔBIC {won.delta_bic:.0f}); held-out RMS "
        f"{_um(f.cv_rms_mm)} → {_um(won.cv_rms_mm_after)} µm ({floor_words(d.floor_estimated)} "
        f"{_um(d.noise_floor_mm)} µm). Add it: {add.format(v)}",
        f"  physics: {get_effect(v).physics}",
    ]
    if get_effect(v).source.kind != "catalogue":
        out.append(f"  (an effect from outside the catalogue: {get_effect(v).source.text()})")
    if v == "zero_step":
        out += [f"  {c.text()}" for c in d.changes]
    if v == "frame_step" and d.frame is not None:
        out.append(f"  {d.frame.text()}")
    return out


def plan_lines(d: Diagnosis, plan_command: str) -> list[str]:
    """The plans offered where the poses cannot decide: how many planned poses would, and the
    command that makes them."""
    if not d.plans:
        return []
    return ["to decide, record planned poses:"] + [
        f"  - {p.text()}: {plan_command} {' '.join(p.args())}" for p in d.plans
    ]


def pointer_lines(d: Diagnosis) -> list[str]:
    """Where an unexplained residual points: the covariates it follows, with their shares."""
    x = d.exploration
    if x is None:
        return []
    if not x.leads:
        return ["  where it points: " + x.summary()]
    out = ["  where it points (the residual regressed on each covariate; share of the excess):"]
    out += [f"    {t.text()}" for t in x.leads[:4]]
    lead = x.leads[0]
    out.append(
        f"  the {lead.covariate.label} points at {lead.points_at}; --effect-file "
        "FILE.py writes an effect with that shape to edit and pass back"
    )
    return out


def _accuracy_lines(d: Diagnosis) -> list[str]:
    """Pose error on held-out poses, and the drawing's, one line each."""
    out = []
    if d.accuracy is not None:
        a = d.accuracy
        floor = (
            f"; {floor_words(d.floor_estimated)} {_um(a.floor_position_rms_mm).strip()} µm, "
            f"{a.floor_orientation_rms_deg:.4f}°"
            if a.floor_position_rms_mm is not None
            else ""
        )
        out.append(f"pose error, held-out: {a.line()}{floor}")
    if d.design_accuracy is not None:
        out.append(
            f"pose error of the drawing (robot.json as designed): {d.design_accuracy.line()}"
        )
    return out


def before_after_text(steps: list[Diagnosis]) -> str:
    """The fall of the error across added effects, side by side: held-out leg-length RMS and
    pose error (the pose from the readings against the tracker's), µm and degrees."""
    estimated = bool(steps) and steps[-1].floor_estimated
    w = 10 if estimated else 8  # the floor column's width
    head = (
        f"{'model':<34}{'held-out':>10}{'blocked':>10}"
        f"{'est.floor' if estimated else 'floor':>{w}}{'pose':>10}{'p95':>9}"
        f"{'angle °':>9}   per-leg held-out"
    )
    lines = [
        "the error as effects are added (µm; pose = position error of the pose the model "
        "computes from the readings, on held-out poses"
        + ("; est.floor: the floor estimated from the residual, no instruments file" * estimated)
        + "):",
        head.rstrip(),
    ]
    first = steps[0].design_accuracy if steps else None
    if first is not None:
        lines.append(
            f"{'design (drawing, all poses)':<34}{_um(first.leg_rms_mm or float('nan')):>10}"
            f"{'':>10}{'':>{w}}{_um(first.position_rms_mm):>10}{_um(first.position_p95_mm):>9}"
            f"{first.orientation_rms_deg:>9.4f}"
        )
    for d in steps:
        f = d.fit
        acc = d.accuracy
        pose = (
            f"{_um(acc.position_rms_mm):>10}{_um(acc.position_p95_mm):>9}{acc.orientation_rms_deg:>9.4f}"
            if acc is not None
            else f"{'':>28}"
        )
        name = getattr(d, "model_name", f.model_name)
        lines.append(
            f"{name:<34}{_um(f.cv_rms_mm):>10}{_um(f.cv_blocked_rms_mm):>10}{_um(d.noise_floor_mm):>{w}}"
            + pose
            + "   "
            + " ".join(f"{1000 * v:5.1f}" for v in f.cv_rms_per_leg)
            + f"   → {d.verdict}"
        )
    last = steps[-1].accuracy if steps else None
    if last is not None and last.floor_position_rms_mm is not None:
        lines.append(
            f"{'pose floor (estimated)' if estimated else 'pose floor (noise alone)':<34}"
            f"{'':>{20 + w}}"
            f"{_um(last.floor_position_rms_mm):>10}{'':>9}"
            f"{last.floor_orientation_rms_deg:>9.4f}"
        )
    return "\n".join(lines)
