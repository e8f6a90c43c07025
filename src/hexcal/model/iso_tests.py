"""Where the standard tests take a hexapod: ISO 9283's test cube and five test poses, and
ISO 230-2's target readings of each leg. The procedure steps ``iso9283`` and ``iso230-2``
visit them; the metrology (:mod:`hexcal.diagnosis.metrology`) finds them again in a session.

**The ISO 9283 cube.** ISO 9283:1998 (its poses to be tested, 6.8) places one cube in the working space, edges
parallel to the base frame, of the largest volume the working space allows, where the robot is
most used. For a hexapod hexcal takes: the measurement frame's axes (the tracker registered to
the base), centred at the robot's home position (where the platform works), orientation the
home orientation, and the largest edge for which every point of a 5 × 5 × 5 grid over the cube
is a pose the robot can take: each leg's reading within ``leg_range_mm`` — or, when robot.json
gives no stroke, within ± :data:`DEFAULT_STROKE_MM` of its reading at home (hexcal's default
stroke, :class:`~hexcal.model.workspace.PoseRanges`) — and each joint within its limit
(``joint_limit_deg``, else :class:`~hexcal.model.workspace.Limits`' 50°). The edge is found by
bisection to 0.1 mm.

**The five test poses** (the same section) lie in the plane through two opposite edges of
the cube, C1–C2 (x from −e/2 to +e/2 at y = z = −e/2) and C7–C8 (at y = z = +e/2): P1 at the
cube's centre, P2–P5 on the plane's diagonals at 10 % of the diagonal's length L = e√3 from the
corners C1, C2, C7, C8 (so at 0.8 of the way from the centre to each corner); every one at the
home orientation. A cycle visits P1, P2, P3, P4, P5 in that order, so each pose is approached
from the same side in every cycle (unidirectional, as the pose accuracy and repeatability test, 7.2, asks); 30 cycles.

**ISO 230-2 targets** (ISO 230-2:2014's target positions and standard test cycle): each leg is an axis of the machine. With the other
five legs held at their home readings, leg k visits :data:`ISO230_TARGETS` target readings
spread irregularly (so a periodic error of the screw does not alias) over the central 80 % of
its range (± :data:`DEFAULT_STROKE_MM` of its reading at home, within ``leg_range_mm``: one
leg moved alone tilts the platform, so its test range stays near home), in the standard test
cycle: from below the first target up through every target,
beyond the last, down through every target and below the first again — an overrun of
:data:`OVERRUN_FRACTION` of the range at each end, so each target is approached from a known
side — :data:`ISO230_CYCLES` times. Every stop is recorded, the overrun poses too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.model.robot import Robot
from hexcal.model.workspace import Limits, PoseRanges, Workspace

#: A leg's stroke about its reading at home when robot.json states no ``leg_range_mm``, mm.
DEFAULT_STROKE_MM = PoseRanges().stroke_mm
#: ISO 9283: cycles of the five test poses for pose accuracy and repeatability.
ISO9283_CYCLES = 30
#: ISO 9283: the test poses sit at this fraction of the cube's diagonal from its corners.
CORNER_FRACTION = 0.1
#: ISO 230-2: target readings per leg, cycles of bidirectional approaches (the standard asks
#: for at least five targets and five approaches in each direction).
ISO230_TARGETS = 5
ISO230_CYCLES = 5
#: ISO 230-2: the overrun past the end targets, as a fraction of the leg's test range.
OVERRUN_FRACTION = 0.05
#: Irregular spacing of the targets over the test range (fractions 0..1), as the standard asks;
#: none at the middle, the leg's home reading, where other tests' poses would join it.
TARGET_FRACTIONS = (0.0, 0.23, 0.56, 0.78, 1.0)
#: The share of a leg's range the targets span (the rest leaves room for the overrun).
TARGET_SPAN = 0.8


@dataclass(frozen=True)
class Cube:
    """ISO 9283's test cube: ``centre`` (3,) mm and ``edge`` mm in the measurement frame, at
    ``rotation`` (3, 3) (the home orientation); ``reason``: what limits its edge."""

    centre: np.ndarray
    edge: float
    rotation: np.ndarray
    reason: str

    @property
    def corners(self) -> dict[str, np.ndarray]:
        """The corners C1, C2, C7, C8 of the test plane, (3,) mm each (module docstring)."""
        h = self.edge / 2.0
        signs = {"C1": (-1, -1, -1), "C2": (1, -1, -1), "C7": (1, 1, 1), "C8": (-1, 1, 1)}
        return {k: self.centre + h * np.array(s, float) for k, s in signs.items()}

    def poses(self) -> tuple[list[str], np.ndarray, np.ndarray]:
        """(labels P1…P5, positions (5, 3) mm, rotations (5, 3, 3)): the test poses."""
        f = 1.0 - 2.0 * CORNER_FRACTION  # from the centre, 0.8 of the way to a corner
        pts = [self.centre] + [self.centre + f * (c - self.centre) for c in self.corners.values()]
        return (
            [f"P{i}" for i in range(1, 6)],
            np.array(pts),
            np.broadcast_to(self.rotation, (5, 3, 3)).copy(),
        )

    def text(self) -> str:
        c = ", ".join(f"{v:.2f}" for v in self.centre)
        return (
            f"ISO 9283 cube: edge {self.edge:.1f} mm centred at home ({c}) mm, at the home "
            f"orientation; {self.reason}"
        )


def _stroke(robot: Robot) -> tuple[np.ndarray, np.ndarray, str]:
    """Per leg (6,) reading limits, mm, and where they come from."""
    ws = Workspace(robot)
    home = np.array([ws.home_leg(k)[1] for k in range(6)]) - robot.offsets
    lo, hi = home - DEFAULT_STROKE_MM, home + DEFAULT_STROKE_MM
    if robot.leg_range_mm is not None:
        return (
            np.full(6, float(robot.leg_range_mm[0])),
            np.full(6, float(robot.leg_range_mm[1])),
            "leg_range_mm",
        )
    return lo, hi, f"± {DEFAULT_STROKE_MM:g} mm of each leg's reading at home"


def _grid_feasible(
    robot: Robot,
    centre: np.ndarray,
    rotation: np.ndarray,
    half: float,
    lo: np.ndarray,
    hi: np.ndarray,
    limits: Limits,
) -> bool:
    g = np.linspace(-half, half, 5)
    pts = centre + np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    rot = np.broadcast_to(rotation, (len(pts), 3, 3))
    ws = Workspace(robot, limits=Limits(limits.base_joint_deg, limits.platform_joint_deg, None))
    if not ws.feasible(pts, rot).all():
        return False
    readings = ws.true_lengths(pts, rot) - robot.offsets
    return bool(((readings >= lo) & (readings <= hi)).all())


def iso9283_cube(robot: Robot, tolerance_mm: float = 0.1) -> Cube:
    """The test cube of ``robot`` (see the module docstring)."""
    ws = Workspace(robot)
    centre, rotation = ws.home_position, ws.home_rotation
    lo, hi, stroke_from = _stroke(robot)
    limit = getattr(robot, "joint_limit_deg", None)
    limits = Limits() if limit is None else Limits(float(limit), float(limit))
    if not _grid_feasible(robot, centre, rotation, 0.0, lo, hi, limits):
        raise ValueError(
            "the robot's home pose is outside its own stroke or joint limits: no ISO 9283 cube "
            "can be centred there; check home, leg_range_mm and joint_limit_deg in robot.json"
        )
    good, bad = 0.0, 4.0 * DEFAULT_STROKE_MM + float(np.max(hi - lo))
    while bad - good > tolerance_mm / 2.0:
        mid = 0.5 * (good + bad)
        if _grid_feasible(robot, centre, rotation, mid, lo, hi, limits):
            good = mid
        else:
            bad = mid
    reason = (
        f"the largest cube whose 5×5×5 grid keeps every reading within {stroke_from} and every "
        f"joint within {limits.base_joint_deg:g}°"
    )
    return Cube(np.asarray(centre, float), 2.0 * good, np.asarray(rotation, float), reason)


def iso9283_sequence(
    robot: Robot, cycles: int = ISO9283_CYCLES
) -> tuple[list[str], np.ndarray, np.ndarray]:
    """(labels (5·cycles,), positions (5·cycles, 3) mm, rotations (5·cycles, 3, 3)): the
    poses an ``iso9283`` step visits, in order (P1 … P5, ``cycles`` times)."""
    labels, P, R = iso9283_cube(robot).poses()
    return labels * cycles, np.tile(P, (cycles, 1)), np.tile(R, (cycles, 1, 1))


@dataclass(frozen=True)
class LegTargets:
    """ISO 230-2 targets of one leg (1..6): ``targets`` (m,) readings mm, ascending; the other
    legs' readings ``hold`` (6,) mm (home); ``overrun`` mm past the end targets."""

    leg: int
    targets: np.ndarray
    hold: np.ndarray
    overrun: float

    def sequence(self, cycles: int = ISO230_CYCLES) -> tuple[np.ndarray, np.ndarray]:
        """(readings (M, 6) mm, direction (M,) ±1): every pose of the test cycle in order, the
        overrun poses included (they are recorded too, so that any reader of the session sees
        from which side each target was approached); ``direction`` is the side each pose is
        approached from (+1 from below)."""
        t = self.targets
        lo, hi = t[0] - self.overrun, t[-1] + self.overrun
        values: list[float] = []
        dirn: list[int] = []
        for _ in range(cycles):
            values += [lo, *t, hi, *t[::-1]]
            dirn += [-1, *[1] * len(t), 1, *[-1] * len(t)]
        readings = np.tile(self.hold, (len(values), 1))
        readings[:, self.leg - 1] = values
        return readings, np.array(dirn)


def iso230_targets(robot: Robot, leg: int) -> LegTargets:
    """Leg ``leg``'s (1..6) targets (see the module docstring)."""
    ws = Workspace(robot)
    hold = np.array([ws.home_leg(k)[1] for k in range(6)]) - robot.offsets
    lo, hi = hold - DEFAULT_STROKE_MM, hold + DEFAULT_STROKE_MM
    if robot.leg_range_mm is not None:  # a single leg moved alone: near home, in its stroke
        lo = np.maximum(lo, float(robot.leg_range_mm[0]))
        hi = np.minimum(hi, float(robot.leg_range_mm[1]))
    k = leg - 1
    span = hi[k] - lo[k]
    first = lo[k] + 0.5 * (1.0 - TARGET_SPAN) * span
    targets = first + TARGET_SPAN * span * np.array(TARGET_FRACTIONS)
    return LegTargets(leg, targets, hold, OVERRUN_FRACTION * span)


def home_rotation(robot: Robot) -> np.ndarray:
    """(3, 3): the robot's home orientation."""
    return Rotation.from_quat(robot.home.quaternion, scalar_first=True).as_matrix()
