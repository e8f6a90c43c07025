"""Plain words first: the opening lines of ``calibrate``, ``diagnose`` and ``validate`` (and of
the text UI's result and diagnosis screens), as the HTML report opens — the verdict in words,
then how close the platform now is against what the instruments allow. The statistics follow
under :data:`STATISTICS`; ``--verbose`` shows them all.

One place for these words: the command line and the text UI both call these functions, and the
diagnosis' sentences are :func:`hexcal.diagnosis.summary.plain_summary`, the report's own.
"""

from __future__ import annotations

import argparse
import math
import textwrap
from collections.abc import Sequence
from typing import Any

from hexcal.estimate.accuracy import PoseAccuracy
from hexcal.io import advice
from hexcal.vocabulary import Outcome, counted, names_an_addition

#: The heading the statistics follow.
STATISTICS = "Statistics"
#: A model whose held-out pose error is within this factor of the floor is at the limit the
#: instruments allow (the factor the diagnosis uses for "at the floor" on leg lengths).
AT_FLOOR = 1.15


def _um(mm: float) -> str:
    """A length in the unit that reads best: µm below 1 mm, else mm."""
    if not math.isfinite(mm):
        return "—"
    return f"{1000 * mm:.0f} µm" if abs(mm) < 1 else f"{mm:.2f} mm"


def pose_error_line(rows: Sequence[PoseAccuracy], floor_mm: float | None = None) -> str:
    """ "Pose error: drawing 2.73 mm → Model 42 51 µm → Model 42 + backlash 4 µm; the
    instruments allow 5 µm" — the position RMS of each model, first to last, against the floor
    (``floor_mm``, else the last row's own). Empty when there is no row."""
    if not rows:
        return ""
    floor = floor_mm if floor_mm is not None else rows[-1].floor_position_rms_mm
    steps = " → ".join(f"{_short(r.model)} {_um(r.position_rms_mm)}" for r in rows)
    kind = "held-out poses" if any(r.heldout for r in rows) else "these poses"
    line = f"Pose error (position RMS, {kind}): {steps}"
    if floor is not None and math.isfinite(floor) and floor > 0:
        ratio = rows[-1].position_rms_mm / floor
        allow = _allow(rows[-1].floor_estimated)
        line += f"; {allow} {_um(floor)} ({ratio:.1f}× that now)."
    return line + ("" if line.endswith(".") else ".")


def _allow(estimated: bool) -> str:
    """Who sets the floor: the instruments, when their noise was stated; else an estimate."""
    return "the estimated floor is" if estimated else "the instruments allow"


def _short(model: str) -> str:
    return "the drawing" if model.startswith("design") else model


def _at_floor(rows: Sequence[PoseAccuracy]) -> bool | None:
    last = rows[-1] if rows else None
    if last is None or not last.floor_position_rms_mm:
        return None
    return bool(last.position_rms_mm <= AT_FLOOR * last.floor_position_rms_mm)


def calibration_summary(
    name: str, accuracy: Sequence[PoseAccuracy], mismatch: Sequence[str], next_step: str
) -> list[str]:
    """The opening of ``hexcal calibrate``: whether the calibrated model (``name``) can be used,
    and its pose error against the floor. ``next_step``: how to find what is missing (a key,
    or a command's line from :mod:`hexcal.io.advice`, printed on a line of its own)."""
    out = []
    command = next_step if advice.is_line(next_step) else None
    at_floor = _at_floor(accuracy)
    if mismatch:
        out.append(
            f"Do not use this model yet: the calibrated {name} does not match the drawing "
            "(see below). Fix the cause (cables, node ids, columns, units) and record again."
        )
    elif at_floor is None and accuracy:
        out.append(
            f"Calibrated {name}; no instrument noise is known, so there is no floor to judge its "
            "pose error against (hexcal diagnose estimates one; --instruments states it)."
        )
    elif at_floor is None:
        out.append(f"Calibrated {name}; no pose error could be measured on these poses.")
    elif at_floor and accuracy[-1].floor_estimated:
        out.append(
            f"The calibrated {name} is at its estimated floor: what is left is no larger than "
            "the noise estimated from the residual (no instruments file)."
        )
    elif at_floor:
        out.append(
            f"The calibrated {name} is as good as the instruments can tell: what is left is "
            "their own noise."
        )
    else:
        out.append(
            f"The calibrated {name} still misses something: the platform's pose error is above "
            f"{'its estimated floor' if accuracy[-1].floor_estimated else 'what the instruments allow'}. "
            f"Find what:{'' if command else ' ' + next_step}"
        )
        if command is not None:
            out.append(command)
    line = pose_error_line(accuracy)
    if line:
        out.append(line)
    return out


def diagnosis_summary(steps: Sequence[Any], args: argparse.Namespace | None = None) -> list[str]:
    """The opening of ``hexcal diagnose``: the report's plain-language summary, then the pose
    error of each model of the chain against the floor, then what to run next with the
    command's own inputs (``args``: its parsed arguments; None: the option alone)."""
    from hexcal.diagnosis.summary import plain_summary

    d = steps[-1]
    out = list(plain_summary(steps))
    rows = [a for a in (steps[0].design_accuracy, *(s.accuracy for s in steps)) if a is not None]
    line = pose_error_line(rows)
    if line:
        out.append(line)
    if not d.verdict or not names_an_addition(d.verdict):
        unasked = args is not None and getattr(args, "effect_file", None) is None
        if args is not None and unasked and d.verdict == Outcome.UNEXPLAINED and _points(d):
            out.append("Next, to write an effect of the shape the residual follows, to edit:")
            effect = advice.beside(args.measurements, "effect", ".py")
            out.append(advice.line(advice.diagnose_command(args, effect_file=effect)))
        return out
    what = "acknowledge them" if d.verdict == Outcome.OUTLIERS else "add it"
    if args is None:
        out.append(f"Next: {what} (--add {d.verdict}), or let --auto add what is named.")
        return out
    out.append(f"Next, to {what} and diagnose again (--auto adds what is named):")
    out.append(advice.line(advice.diagnose_command(args, add=[d.verdict])))
    return out


def _points(d: Any) -> bool:
    """Whether an unexplained residual follows a covariate an effect file can take."""
    return d.exploration is not None and d.exploration.lead is not None


def verdict_words(d: Any) -> str:
    """A diagnosis' verdict as one short sentence (the text UI's first line)."""
    if d.verdict == Outcome.NONE and getattr(d, "floor_estimated", False):
        return "Nothing is missing: what is left is at the estimated noise floor."
    if d.verdict == Outcome.NONE:
        return "Nothing is missing: what is left is the instruments' own noise."
    if d.verdict == Outcome.UNEXPLAINED:
        return "Something no catalogue effect describes remains (see below)."
    if d.verdict == Outcome.NOISE_UNDERSTATED:
        return f"The instruments look about {d.noise_factor:.1f}× noisier than stated."
    if d.verdict == Outcome.OUTLIERS:
        return (
            f"{counted(len(d.outliers), 'pose')} disagree grossly with every model: look at them."
        )
    return f"The model lacks {d.verdict}: press a to add it."


def pose_against_floor(a: PoseAccuracy | None) -> str:
    """ "pose error 51 µm, the instruments allow 5 µm (10.9×)" (empty without a floor)."""
    if a is None or not a.floor_position_rms_mm or not math.isfinite(a.position_rms_mm):
        return ""
    ratio = a.position_rms_mm / a.floor_position_rms_mm
    return (
        f"pose error {_um(a.position_rms_mm)}, {_allow(a.floor_estimated)} "
        f"{_um(a.floor_position_rms_mm)} ({ratio:.1f}×)"
    )


def validation_summary(v: Any) -> list[str]:
    """The opening of ``hexcal validate``: does the model hold on this session, in words, and
    the pose error against the floor."""
    if v.own_session:
        first = (
            "This is not a validation: these are the poses the model was fitted on: "
            f"{v.own_session}. Validate on a second session."
        )
    elif v.verdict == Outcome.NONE:
        down_to = (
            "the estimated noise (no instruments file)"
            if v.floor_estimated
            else "the instruments' own noise"
        )
        first = f"The model holds on this session: {v.model} predicts it down to {down_to}."
    elif v.verdict == Outcome.UNEXPLAINED:
        noise = "the estimated noise" if v.floor_estimated else "the instruments' noise"
        first = (
            f"The model does not hold on this session: {v.model} misses these poses by more "
            f"than {noise}, and no catalogue effect explains it (see below)."
        )
    else:
        first = (
            f"The model does not hold on this session: it lacks {v.verdict}. Calibrate again "
            f"with --add {v.verdict}, from a session that shows it."
        )
    out = [first]
    line = pose_error_line([v.accuracy])
    if line:
        out.append(line)
    return out


def opening(lines: Sequence[str], width: int = 96) -> str:
    """The summary lines wrapped at ``width``, followed by the statistics' heading."""
    body = "\n".join(
        s if advice.is_line(s) else textwrap.fill(s, width, break_on_hyphens=False)
        for s in lines
        if s
    )
    return f"{body}\n\n{STATISTICS}\n{'-' * len(STATISTICS)}"
