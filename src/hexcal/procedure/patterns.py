"""Steps that visit set targets: ``iso9283`` (ISO 9283's five test poses in the test cube) and
``iso230-2`` (each leg through ISO 230-2's target readings), computed from the session's robot
by :mod:`hexcal.model.iso_tests`. A procedure step names its pattern (``pattern =
"iso9283"``); the operator, or a motion controller, moves to the step's next target before
each pose is recorded.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hexcal.errors import HexcalError
from hexcal.model.iso_tests import (
    ISO230_CYCLES,
    ISO230_TARGETS,
    ISO9283_CYCLES,
    iso230_targets,
    iso9283_sequence,
)
from hexcal.model.robot import Robot

#: The patterns a step may name, with their default cycle counts.
PATTERNS = {"iso9283": ISO9283_CYCLES, "iso230-2": ISO230_CYCLES}


def poses_per_cycle(pattern: str) -> int:
    """Poses one cycle of ``pattern`` records: five test poses; six legs × (targets and the
    two overrun stops) × both directions."""
    if pattern == "iso9283":
        return 5
    return 6 * 2 * (ISO230_TARGETS + 1)


@dataclass(frozen=True)
class Target:
    """Where the next pose of a pattern step is taken: ``label`` for the operator, and either
    a pose (``position`` (3,) mm, ``rotation`` (3, 3)) or six ``readings`` (6,) mm."""

    label: str
    position: np.ndarray | None = None
    rotation: np.ndarray | None = None
    readings: np.ndarray | None = None


#: The targets of the last robots asked about, by their robot.json text: a step asks once per
#: pose, and the cube's bisection is worth keeping.
_CACHE: dict[tuple[str, str, int], tuple] = {}


def _targets(pattern: str, design: Robot, n: int) -> tuple:
    key = (design.model_dump_json(), pattern, n)
    if key not in _CACHE:
        if len(_CACHE) > 8:
            _CACHE.clear()
        if pattern == "iso9283":
            _CACHE[key] = iso9283_sequence(design, 1)
        else:
            _CACHE[key] = tuple(iso230_targets(design, leg).sequence(n) for leg in range(1, 7))
    return _CACHE[key]


def target(pattern: str, design: Robot, index: int, cycles: int | None = None) -> Target:
    """The ``index``-th (0-based, wrapping) target of ``pattern`` for the robot ``design``."""
    n = cycles or PATTERNS[pattern]
    if pattern == "iso9283":
        labels, P, R = _targets(pattern, design, n)
        i = index % len(labels)
        cycle = index // len(labels) % n + 1
        where = ", ".join(f"{v:.1f}" for v in P[i])
        return Target(f"{labels[i]} at ({where}) mm, cycle {cycle} of {n}", P[i], R[i])
    per_leg = poses_per_cycle(pattern) // 6 * n
    leg = index // per_leg % 6 + 1
    readings, direction = _targets(pattern, design, n)[leg - 1]
    j = index % per_leg
    side = "from below" if direction[j] > 0 else "from above"
    return Target(f"leg {leg} to {readings[j, leg - 1]:.3f} mm {side}", readings=readings[j])


def move_to(mover, t: Target) -> str:
    """Move a motion controller to the target (``move_near`` for a pose, ``move_readings``
    for readings); the operator's sentence."""
    if t.readings is not None:
        if not hasattr(mover, "move_readings"):
            raise HexcalError("this motion controller cannot move the legs to given readings")
        mover.move_readings(t.readings)
    else:
        if not hasattr(mover, "move_near"):
            raise HexcalError("this motion controller cannot move to a given pose")
        mover.move_near(t.position, t.rotation)
    return f"moved to {t.label}"
