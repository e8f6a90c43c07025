"""Whole-robot linear calibration: for each leg, the method that the session's pose sets allow.

Model 36 (offsets known):  §3.2 from the leg's Type I set; else §3.3 from its Type II and
Type III sets; else the free-pose linear form over every pose.
Model 42 (offsets unknown): §3.3 from Type II + Type III, offset by eq. (19) over every pose;
else the free-pose linear form. (A Type I set alone cannot give Model 42: along the clamped
direction the base point and the offset are one unknown.)

``form="direct"`` swaps the paper's differenced systems for the direct forms of
:mod:`hexcal.estimate.solvers.direct`; the choice of method per leg is the same.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from hexcal.errors import RefusedError
from hexcal.estimate.solvers import direct, free, paper
from hexcal.estimate.solvers.checks import (
    DegenerateSet,
    check_type_i,
    check_type_ii,
    check_type_iii,
)
from hexcal.vocabulary import LEG_CONSTRAINTS, Constraint, ModelKind

Form = Literal["paper", "direct"]


@dataclass(frozen=True)
class LegResult:
    """One leg's linear solution: a (3,) mm base frame, b (3,) mm platform frame, offset mm."""

    leg: int
    method: str
    detail: str
    a: np.ndarray
    b: np.ndarray
    offset: float

    @property
    def label(self) -> str:
        return f"{self.method} ({self.detail})"


@dataclass(frozen=True)
class LinearCalibration:
    """The linear stage's geometry: a (6, 3), b (6, 3), offsets (6,) mm, and per-leg methods."""

    model: ModelKind
    form: str
    legs: tuple[LegResult, ...]

    @property
    def a(self) -> np.ndarray:
        return np.array([leg.a for leg in self.legs])

    @property
    def b(self) -> np.ndarray:
        return np.array([leg.b for leg in self.legs])

    @property
    def offsets(self) -> np.ndarray:
        return np.array([leg.offset for leg in self.legs])

    @property
    def methods(self) -> list[str]:
        return [leg.label for leg in self.legs]


class CalibrationRefused(RefusedError, ValueError):
    """No method could calibrate one or more legs; the message lists, per leg, what to record."""

    def __init__(self, reasons: dict[int, list[str]]):
        self.reasons = reasons
        lines = ["the session cannot calibrate every leg:"]
        for leg, msgs in sorted(reasons.items()):
            lines.append(f"  leg {leg}:")
            lines.extend(f"    - {m}" for m in msgs)
        super().__init__("\n".join(lines))


def _solve_leg(
    k: int,
    P: np.ndarray,
    R: np.ndarray,
    rho: np.ndarray,
    leg: np.ndarray,
    constraint: np.ndarray,
    model: ModelKind,
    design_offset: float,
    form: Form,
) -> tuple[LegResult | None, list[str]]:
    """Try the methods in order for leg k (1-based); return the result or the reasons."""
    reasons: list[str] = []
    sets = {c: (leg == k) & (constraint == c) for c in LEG_CONSTRAINTS}
    n = {c: int(m.sum()) for c, m in sets.items()}
    r = rho[:, k - 1]

    if model == ModelKind.M36:
        m = sets[Constraint.DIRECTION]
        if n[Constraint.DIRECTION]:
            try:
                check_type_i(k, P[m], R[m], r[m] + design_offset)
                length = r[m] + design_offset
                if form == "paper":
                    b, a = paper.type_i_paper(P[m], R[m], length)
                else:
                    b, a, _ = direct.type_i_direct(P[m], R[m], length)
                return LegResult(
                    k, "§3.2", f"{n[Constraint.DIRECTION]} Type I poses", a, b, design_offset
                ), []
            except DegenerateSet as exc:
                reasons.append(str(exc))
        else:
            reasons.append("no Type I (direction-clamped) poses for §3.2")

    n2, n3 = n[Constraint.DIRECTION_LENGTH], n[Constraint.LENGTH]
    m2, m3 = sets[Constraint.DIRECTION_LENGTH], sets[Constraint.LENGTH]
    if n2 and n3:
        try:
            check_type_ii(k, P[m2], R[m2])
            b = (
                paper.type_ii_paper(P[m2], R[m2])
                if form == "paper"
                else direct.type_ii_direct(P[m2], R[m2])[0]
            )
            check_type_iii(k, P[m3], R[m3], b)
            if form == "paper":
                a = paper.type_iii_paper(P[m3], R[m3], b)
            else:
                a = direct.type_iii_direct(P[m3], R[m3], b)[0]
            if model == ModelKind.M42:
                offset = float(paper.offset_eq19(P, R, b, a, r))
                detail = f"{n2} Type II + {n3} Type III poses, offset by eq. 19 over {len(P)} poses"
            else:
                offset = design_offset
                detail = f"{n2} Type II + {n3} Type III poses"
            return LegResult(k, "§3.3", detail, a, b, offset), []
        except DegenerateSet as exc:
            reasons.append(str(exc))
    else:
        missing = [
            name
            for c, name in (
                (Constraint.DIRECTION_LENGTH, "Type II (direction and length clamped)"),
                (Constraint.LENGTH, "Type III (length clamped)"),
            )
            if not n[c]
        ]
        reasons.append(f"§3.3 needs {' and '.join(missing)} poses")

    # Every pose of the session is a free pose for this leg's inverse kinematics.
    if len(P) >= free.MIN_POSES:
        from hexcal.estimate.solvers.linalg import scaled_singular_values

        mat, _ = free.free_system(P, R, r, None if model == ModelKind.M42 else design_offset)
        s = scaled_singular_values(mat)
        if s[0] / max(s[-1], 1e-300) < 1e8:
            b, a, off = free.free_linear(P, R, r, None if model == ModelKind.M42 else design_offset)
            return LegResult(k, "free-linear", f"{len(P)} poses, all types", a, b, off), []
        reasons.append(
            f"the {len(P)} poses are too alike for the free-pose linear form: move and tilt the platform more widely"
        )
    else:
        reasons.append(
            f"the free-pose linear form needs at least {free.MIN_POSES} poses ({len(P)} recorded)"
        )
    return None, reasons


def calibrate_linear(
    position: np.ndarray,
    rotation: np.ndarray,
    readings: np.ndarray,
    leg: np.ndarray,
    constraint: np.ndarray,
    model: ModelKind,
    design_offsets: np.ndarray,
    form: Form = "paper",
) -> LinearCalibration:
    """Linear geometry of all six legs.

    position (N, 3) mm, rotation (N, 3, 3), readings (N, 6) mm, leg (N,) clamped leg 1..6 or 0,
    constraint (N,) str; design_offsets (6,) mm are used as known offsets for Model 36.
    Raises :class:`CalibrationRefused` naming every leg that no method could serve and why.
    """
    if model not in tuple(ModelKind):
        raise ValueError(f"model must be 36 or 42, not {model}")
    constraint = np.asarray(constraint, dtype=object)
    leg = np.asarray(leg)
    results, refused = [], {}
    for k in range(1, 7):
        res, reasons = _solve_leg(
            k,
            position,
            rotation,
            readings,
            leg,
            constraint,
            model,
            float(design_offsets[k - 1]),
            form,
        )
        if res is None:
            refused[k] = reasons
        else:
            results.append(res)
    if refused:
        raise CalibrationRefused(refused)
    return LinearCalibration(model, form, tuple(results))
