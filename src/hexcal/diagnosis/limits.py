"""Poses with a leg at the end of its stroke or a joint at its limit.

A leg held against its end stop no longer follows the model (the controller's command is
clipped, the leg presses on its stop, the joint binds), and a pose taken there pulls the fit.
With ``leg_range_mm`` in robot.json, a reading within a small margin of either end (or beyond)
is at the stroke's end. Without it, the data still tell: readings that pile up at a leg's
highest (or lowest) value — several poses within a fraction of a millimetre of each other at the
extreme, where freely chosen poses spread out — mark an end stop the commands ran into. With
``joint_limit_deg``, a joint within a degree of its cone's edge is flagged too.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hexcal.model.robot import Robot

#: The margin at a stroke's end: this fraction of the leg's span of readings…
END_FRACTION = 0.002
#: …but at least this, mm (or 3σ of the readings when the noise is known, if larger).
END_MIN_MM = 0.05
#: Readings piled up at an extreme: at least this many poses…
PILE_MIN_POSES = 3
#: …and this share of the session's.
PILE_MIN_SHARE = 0.02
#: A joint within this of its cone's edge, deg, is at its limit.
JOINT_MARGIN_DEG = 1.0
#: The reading noise counts this many σ at a stroke's end: a reading beyond it by more is not
#: noise (1 in 3.5 million readings at the end exceeds 5σ by chance).
END_NOISE_K = 5.0
#: The advice on poses at an end when robot.json already gives the stroke.
LEAVE_OUT = (
    "a leg against its end stop does not follow the model: leave these poses out with "
    "--exclude-at-limits"
)
#: A calibration moves each leg over at least this share of its stroke: readings that fit the
#: stroke once scaled, but then use less of it, are not a unit slip (÷1000 fits any stroke).
USED_STROKE_SHARE = 0.25
#: Known factors between units of length, for the stroke's likely cause: factor → its name.
_UNIT_SLIPS = {10.0: "cm", 25.4: "inches", 1000.0: "m"}


@dataclass
class LegAtEnd:
    leg: int  #: 1-based
    end: str  #: "upper" or "lower"
    reading_mm: float  #: the end's reading
    rows: list[int]  #: 0-based poses at that end
    source: str  #: "leg_range_mm" or "the readings pile up there"


@dataclass
class Limits:
    """The poses at a stroke's end or a joint's limit (0-based rows), and why."""

    legs: list[LegAtEnd] = field(default_factory=list)
    joints: dict[int, list[int]] = field(default_factory=dict)  #: leg → rows

    @property
    def rows(self) -> list[int]:
        out = {r for e in self.legs for r in e.rows} | {
            r for rs in self.joints.values() for r in rs
        }
        return sorted(out)

    def lines(self, meas) -> list[str]:
        """One line per leg at an end or joint at its limit, for the operator."""
        out = []
        for e in self.legs:
            ids = ", ".join(f"#{int(meas.pose_id[r])}" for r in e.rows[:8])
            more = f" and {len(e.rows) - 8} more" if len(e.rows) > 8 else ""
            out.append(
                f"leg {e.leg} sits at the {e.end} end of its stroke ({e.reading_mm:.2f} mm; "
                f"{e.source}) in {len(e.rows)} poses: {ids}{more}"
            )
        for leg, rows in sorted(self.joints.items()):
            ids = ", ".join(f"#{int(meas.pose_id[r])}" for r in rows[:8])
            out.append(f"leg {leg}'s joint is at its limit in {len(rows)} poses: {ids}")
        return out

    def to_dict(self, meas) -> dict:
        return {
            "legs": [
                {
                    "leg": e.leg,
                    "end": e.end,
                    "reading_mm": e.reading_mm,
                    "poses": [int(meas.pose_id[r]) for r in e.rows],
                    "source": e.source,
                }
                for e in self.legs
            ],
            "joints": {
                str(leg): [int(meas.pose_id[r]) for r in rows] for leg, rows in self.joints.items()
            },
            "pose_ids": [int(meas.pose_id[r]) for r in self.rows],
        }


def end_margin_mm(span_mm: float, reading_sigma_mm: float | None) -> float:
    """A stroke end's margin, mm: :data:`END_FRACTION` of the leg's span of readings
    ``span_mm``, at least :data:`END_MIN_MM` and :data:`END_NOISE_K` σ of the reading noise
    when it is known. Within it of an end a reading is at the end; beyond it past the end, it
    is outside the stroke."""
    tol = max(END_FRACTION * span_mm, END_MIN_MM)
    if reading_sigma_mm is not None:
        tol = max(tol, END_NOISE_K * reading_sigma_mm)
    return tol


def advice(design: Robot) -> str:
    """What to do with the poses at a stroke's end: never asks for ``leg_range_mm`` when
    robot.json already gives it."""
    if design.leg_range_mm is None:
        return (
            "a leg against its end stop does not follow the model: give leg_range_mm in "
            "robot.json, or leave these poses out with --exclude-at-limits"
        )
    return LEAVE_OUT


def at_limits(meas, design: Robot, reading_sigma_mm: float | None = None) -> Limits:
    """The poses of the table ``meas`` at a stroke's end or a joint's limit (module docstring);
    a reading beyond ``leg_range_mm`` by more than :func:`end_margin_mm` is not at the end
    (:func:`beyond_stroke` names it)."""
    rho = meas.readings
    out = Limits()
    span = np.ptp(rho, axis=0)
    for k in range(6):
        tol = end_margin_mm(float(span[k]), reading_sigma_mm)
        x = rho[:, k]
        if design.leg_range_mm is not None:
            lo, hi = design.leg_range_mm
            ends = (
                ("upper", hi, (x >= hi - tol) & (x <= hi + tol)),
                ("lower", lo, (x <= lo + tol) & (x >= lo - tol)),
            )
            source = "leg_range_mm"
        else:
            need = max(PILE_MIN_POSES, int(np.ceil(PILE_MIN_SHARE * len(x))))
            top, bottom = float(x.max()), float(x.min())
            up, down = x >= top - tol, x <= bottom + tol
            ends = (
                ("upper", top, up if up.sum() >= need else np.zeros_like(up)),
                ("lower", bottom, down if down.sum() >= need else np.zeros_like(down)),
            )
            source = "the readings pile up there"
        for end, value, mask in ends:
            if mask.any():
                out.legs.append(
                    LegAtEnd(k + 1, end, float(value), np.where(mask)[0].tolist(), source)
                )
    limit = getattr(design, "joint_limit_deg", None)
    if limit is not None:
        from hexcal.estimate.predict import LegModel, Poses

        model = LegModel(design)
        base, plat = model.joint_angles(Poses(meas.position, meas.rotations.as_matrix()))
        worst = np.maximum(base, plat)
        for k in range(6):
            rows = np.where(worst[:, k] >= limit - JOINT_MARGIN_DEG)[0].tolist()
            if rows:
                out.joints[k + 1] = rows
    return out


@dataclass
class LegBeyond:
    """One leg's readings beyond its stroke by more than the end's margin."""

    leg: int  #: 1-based
    rows: list[int]  #: 0-based poses beyond the stroke
    worst_mm: float  #: how far the farthest lies beyond its end, mm
    end: str  #: the end it lies beyond: "upper" or "lower"


def beyond_stroke(meas, design: Robot, reading_sigma_mm: float | None = None) -> list[LegBeyond]:
    """The legs of the table ``meas`` with readings beyond ``leg_range_mm`` by more than
    :func:`end_margin_mm` (empty when robot.json gives no stroke)."""
    if design.leg_range_mm is None or len(meas) == 0:
        return []
    lo, hi = (float(v) for v in design.leg_range_mm)
    rho = meas.readings
    span = np.ptp(rho, axis=0)
    out = []
    for k in range(6):
        tol = end_margin_mm(float(span[k]), reading_sigma_mm)
        above, below = rho[:, k] - hi, lo - rho[:, k]
        past = np.maximum(above, below)
        rows = np.where(past > tol)[0]
        if len(rows):
            worst = int(rows[np.argmax(past[rows])])
            end = "upper" if above[worst] > below[worst] else "lower"
            out.append(LegBeyond(k + 1, rows.tolist(), float(past[worst]), end))
    return out


def _likely_cause(meas, design: Robot, found: list[LegBeyond]) -> str:
    """The likely cause of readings beyond the stroke, most likely first: a unit slip when the
    readings scaled by a known factor fit the stroke and use a share of it, an offset slip when each leg's readings
    span no more than the stroke (they are shifted), and always a wrong range."""
    lo, hi = (float(v) for v in design.leg_range_mm or (0.0, 0.0))
    legs = [f.leg - 1 for f in found]
    rho = meas.readings[:, legs]
    causes = []
    for factor, unit in _UNIT_SLIPS.items():
        for scaled, what in (
            (rho * factor, f"in {unit}: multiply them by {factor:g}"),
            (rho / factor, f"in 1/{factor:g} mm: divide them by {factor:g}"),
        ):
            fits = np.all((scaled >= lo - END_MIN_MM) & (scaled <= hi + END_MIN_MM))
            if fits and np.all(np.ptp(scaled, axis=0) >= USED_STROKE_SHARE * (hi - lo)):
                causes.append(f"a unit slip: the readings look {what} (then they fit the stroke)")
    if np.all(np.ptp(rho, axis=0) <= hi - lo):
        shift = float(np.median(np.where(rho > hi, rho - hi, np.where(rho < lo, rho - lo, 0.0))))
        causes.append(
            f"an offset slip: the readings span no more than the stroke but sit about "
            f"{shift:+.1f} mm past it (zeroed elsewhere, homed again, or the leg's length logged "
            "with its offset added in place of its reading); correct the readings' zero"
        )
    causes.append(
        f"a wrong range: leg_range_mm [{lo:g}, {hi:g}] in robot.json is not this robot's stroke "
        "on readings; give the stroke its encoders read"
    )
    return "".join(f"\n  {i}. {c}" for i, c in enumerate(causes, 1))


def stroke_message(meas, design: Robot, found: list[LegBeyond], source: str) -> str:
    """The refusal of readings beyond the stroke: the legs, how far, the poses, the likely
    cause (``found`` from :func:`beyond_stroke`, non-empty; ``source`` names the table)."""
    lo, hi = design.leg_range_mm or (0.0, 0.0)
    lines = []
    for f in found:
        ids = ", ".join(f"#{int(meas.pose_id[r])}" for r in f.rows[:5])
        more = f" and {len(f.rows) - 5} more" if len(f.rows) > 5 else ""
        lines.append(
            f"  leg {f.leg}: {len(f.rows)} of {len(meas)} readings beyond the stroke, up to "
            f"{f.worst_mm:.4g} mm past its {f.end} end (poses {ids}{more})"
        )
    legs = ", ".join(str(f.leg) for f in found)
    return (
        f"{source}: {'leg' if len(found) == 1 else 'legs'} {legs} read beyond the stroke "
        f"(leg_range_mm [{lo:g}, {hi:g}] mm on readings in robot.json) by more than the "
        "reading noise; no reading can lie there, so nothing was fitted:\n"
        + "\n".join(lines)
        + f"\nthe likely causes, most likely first:{_likely_cause(meas, design, found)}"
    )
