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


def at_limits(meas, design: Robot, reading_sigma_mm: float | None = None) -> Limits:
    """The poses of the table ``meas`` at a stroke's end or a joint's limit (module docstring)."""
    rho = meas.readings
    out = Limits()
    span = np.ptp(rho, axis=0)
    for k in range(6):
        tol = max(END_FRACTION * float(span[k]), END_MIN_MM)
        if reading_sigma_mm is not None:
            tol = max(tol, 3.0 * reading_sigma_mm)
        x = rho[:, k]
        if design.leg_range_mm is not None:
            lo, hi = design.leg_range_mm
            ends = (("upper", hi, x >= hi - tol), ("lower", lo, x <= lo + tol))
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
