"""Refuse pose sets that are too small or degenerate, and tell the operator what motion to add.

The checks look at the motion itself (length range, rotation spread, number of rotation axes,
spread of the clamped point) because that is what the operator can change; a final numerical
rank test catches anything they miss.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.errors import RefusedError
from hexcal.estimate.solvers.linalg import scaled_singular_values
from hexcal.vocabulary import Constraint

#: Smallest useful spread of the clamped leg's length in a Type I set, mm.
MIN_LENGTH_RANGE_MM = 2.0
#: Smallest useful rotation of the platform within a set, degrees.
MIN_ROTATION_DEG = 1.0
#: A second rotation axis must carry at least this share of the first one's spread.
MIN_SECOND_AXIS_RATIO = 0.1
#: Scaled condition number beyond which a linear system is treated as rank deficient.
MAX_CONDITION = 1e8

MIN_POSES = {Constraint.DIRECTION: 3, Constraint.DIRECTION_LENGTH: 3, Constraint.LENGTH: 4}
PAPER_NAMES = {
    Constraint.DIRECTION: "Type I (direction clamped)",
    Constraint.DIRECTION_LENGTH: "Type II (direction and length clamped)",
    Constraint.LENGTH: "Type III (length clamped)",
}


class DegenerateSet(RefusedError, ValueError):
    """A constrained pose set cannot determine the leg's parameters; the message says why and
    which motion to add."""

    def __init__(self, leg: int, constraint: Constraint, message: str):
        self.leg, self.constraint = leg, constraint
        super().__init__(f"leg {leg}, {PAPER_NAMES.get(constraint, constraint)} poses: {message}")


def _rotation_spread(R: np.ndarray) -> tuple[float, float, np.ndarray]:
    """Largest and second principal spread (deg) of rotations (N, 3, 3) about their mean, and
    the principal axis (3,) in the measurement frame."""
    rot = Rotation.from_matrix(R)
    rel = (rot * rot.mean().inv()).as_rotvec(degrees=True)  # measurement-frame rotation vectors
    centred = rel - rel.mean(axis=0)
    _, s, vt = np.linalg.svd(centred, full_matrices=False)
    s = s / np.sqrt(max(len(R) - 1, 1))
    s = np.pad(s, (0, 3 - len(s)))
    return float(s[0]), float(s[1]), vt[0]


def _check_count(leg: int, constraint: Constraint, n: int) -> None:
    need = MIN_POSES[constraint]
    if n < need:
        raise DegenerateSet(
            leg,
            constraint,
            f"{n} recorded, at least {need} needed (7 or more advised): record more poses",
        )


def _check_rotations(leg: int, constraint: Constraint, R: np.ndarray, pivot: str) -> None:
    s1, s2, axis = _rotation_spread(R)
    if s1 < MIN_ROTATION_DEG:
        raise DegenerateSet(
            leg,
            constraint,
            f"the platform hardly rotated ({s1:.2f} deg spread): tilt it about {pivot} by ±5 deg or more, about two different axes",
        )
    if s2 < MIN_SECOND_AXIS_RATIO * s1:
        ax = np.round(axis, 2).tolist()
        raise DegenerateSet(
            leg,
            constraint,
            f"all rotations are about one axis (≈ {ax} in the tracker frame; second-axis spread "
            f"{s2:.2f} deg against {s1:.2f} deg): tilt the platform about a second, perpendicular axis too",
        )


def _check_rank(leg: int, constraint: Constraint, m: np.ndarray) -> None:
    s = scaled_singular_values(m)
    cond = s[0] / max(s[-1], 1e-300)
    if cond > MAX_CONDITION:
        raise DegenerateSet(
            leg,
            constraint,
            f"the linear system is rank deficient (condition number {cond:.2g}): the poses do not vary enough; "
            "add poses with larger and more varied motions",
        )


def check_type_i(leg: int, P: np.ndarray, R: np.ndarray, reading: np.ndarray) -> None:
    """Type I: the clamped leg must change length and the platform must rotate about two axes."""
    from hexcal.estimate.solvers.direct import type_i_system

    _check_count(leg, Constraint.DIRECTION, len(P))
    span = float(np.ptp(reading))
    if span < MIN_LENGTH_RANGE_MM:
        raise DegenerateSet(
            leg,
            Constraint.DIRECTION,
            f"the clamped leg's length hardly changed ({span:.2f} mm range): extend and retract leg {leg} "
            f"along its clamped direction by ±10 mm or more",
        )
    _check_rotations(leg, Constraint.DIRECTION, R, f"leg {leg}'s platform joint")
    _check_rank(leg, Constraint.DIRECTION, type_i_system(P, R, reading)[0])


def check_type_ii(leg: int, P: np.ndarray, R: np.ndarray) -> None:
    """Type II: the platform must rotate about its clamped joint, about at least two axes."""
    from hexcal.estimate.solvers.direct import type_ii_system

    _check_count(leg, Constraint.DIRECTION_LENGTH, len(P))
    _check_rotations(leg, Constraint.DIRECTION_LENGTH, R, f"leg {leg}'s platform joint")
    _check_rank(leg, Constraint.DIRECTION_LENGTH, type_ii_system(P, R)[0])


def check_type_iii(leg: int, P: np.ndarray, R: np.ndarray, b: np.ndarray) -> None:
    """Type III: the leg's platform end must sweep a patch of its sphere, not a line or a circle."""
    from hexcal.estimate.solvers.paper import platform_point_positions

    _check_count(leg, Constraint.LENGTH, len(P))
    v = platform_point_positions(P, R, b)
    w = v - v.mean(axis=0)
    s = np.linalg.svd(w, compute_uv=False) / np.sqrt(len(v) - 1)
    if s[0] < 1.0:
        raise DegenerateSet(
            leg,
            Constraint.LENGTH,
            f"the leg's end hardly moved ({s[0]:.2f} mm): swing leg {leg} about its base joint by ±5 deg or more in two directions",
        )
    if s[1] < MIN_SECOND_AXIS_RATIO * s[0]:
        raise DegenerateSet(
            leg,
            Constraint.LENGTH,
            f"the leg swung in one direction only ({s[0]:.1f} mm against {s[1]:.1f} mm across): swing leg {leg} sideways too",
        )
    m = np.concatenate([2.0 * w, np.ones((len(w), 1))], axis=1)
    _check_rank(leg, Constraint.LENGTH, m)
