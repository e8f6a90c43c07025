"""The mock motion controller: moves the simulated platform through a procedure, with a leg
clamped as the operator clamped it.

A clamp is set on the robot as it stands: clamping leg k's *direction* fixes the line through
its base point A_k (Type I); its *length* fixes |B_k − A_k| (Type III); both fix the point B_k in
space (Type II). From then on every pose the controller moves to respects that constraint on the
*true* geometry — which is what the calibration must recover — and :meth:`move_to` refuses a
commanded pose that would break it, as a real clamp would stall the platform.

A clamp can be made to slip (:meth:`MockMotionController.slip`): from then on each move lets the
held quantity creep — the clamped length by ``mm_per_move``, the clamped direction by
``deg_per_move`` about a fixed axis, the clamped point by ``mm_per_move`` along a fixed
direction across the leg (its direction clamp giving way) — as a clamp that was not tightened
enough does under the platform's load. The controller does not know about the slip (a real one
would not); the acquisition side has to notice it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.mock_hw.robot import MockRobot
from hexcal.model.workspace import NoFeasiblePose
from hexcal.procedure.recording import MotionError
from hexcal.sim.simulate import PoseRanges, Simulator
from hexcal.vocabulary import LEG_CONSTRAINTS, Constraint

#: The clamp kinds, as the measurement table names the constraint they impose.
CLAMPS = LEG_CONSTRAINTS


@dataclass(frozen=True)
class Clamp:
    """A clamped leg (1..6) and what it holds, on the true geometry: ``direction`` (3,) unit,
    ``length`` mm (|B_k − A_k|), ``point`` (3,) mm (B_k in the tracker frame)."""

    leg: int
    constraint: Constraint
    direction: np.ndarray
    length: float
    point: np.ndarray


@dataclass(frozen=True)
class Slip:
    """How a slipping clamp creeps per move: mm (length, point), deg (direction)."""

    mm_per_move: float = 0.0
    deg_per_move: float = 0.0


class MockMotionController:
    """Moves a :class:`~hexcal.mock_hw.robot.MockRobot`; poses are drawn as a procedure's
    operator would move the platform (``ranges`` as in :class:`~hexcal.sim.simulate.PoseRanges`).

    ``tolerance_mm``: how far a commanded pose may break the clamp's constraint before
    :meth:`move_to` refuses it.
    """

    def __init__(
        self,
        robot: MockRobot,
        ranges: PoseRanges | None = None,
        seed: int = 0,
        tolerance_mm: float = 1e-6,
    ):
        self.robot = robot
        # Its own simulator on the same truth: draws feasible poses, never measures.
        self.sim = Simulator(robot.truth, ranges=ranges or PoseRanges(), limits=robot.sim.limits)
        self.tolerance_mm = tolerance_mm
        self._rng = np.random.default_rng([seed, 0x4D4F54])
        self.clamp_state: Clamp | None = None
        self._slip: Slip | None = None
        self._slip_axis = np.zeros(3)
        self.moves = 0
        #: Called before each move: the mock rig waits there for an instant between the
        #: devices' measurements (:func:`hexcal.mock_hw.rig.mock_rig`). None: move at once.
        self.before_move: Callable[[], None] | None = None
        #: Told the ``robot.clock()`` time (s) from which each pose is in effect (the mock rig
        #: starts the next still window there). None: nobody is told.
        self.on_move: Callable[[float], None] | None = None

    # -- clamping ---------------------------------------------------------------------------
    def _leg_now(self, k: int) -> tuple[np.ndarray, float, np.ndarray]:
        """Leg k (0-based) at the current true pose: unit direction, length mm, B_k (3,) mm."""
        P, R = self.robot.true_pose()
        point = P + R @ self.robot.truth.b[k]
        v = point - self.robot.truth.a[k]
        length = float(np.linalg.norm(v))
        return v / length, length, point

    def clamp(self, leg: int, constraint: Constraint | str) -> Clamp:
        """Clamp leg ``leg`` (1..6) as it stands: ``constraint`` one of :data:`CLAMPS`."""
        if constraint not in CLAMPS:
            raise MotionError(f"unknown clamp {constraint!r}; use one of {', '.join(CLAMPS)}")
        if not 1 <= leg <= 6:
            raise MotionError(f"leg {leg} does not exist; legs are 1..6")
        if self.clamp_state is not None:
            raise MotionError(
                f"leg {self.clamp_state.leg} is still clamped ({self.clamp_state.constraint}); "
                "release it first"
            )
        u, length, point = self._leg_now(leg - 1)
        self.clamp_state = Clamp(leg, Constraint(constraint), u, length, point)
        self._slip = None
        return self.clamp_state

    def release(self) -> None:
        """Release the clamp (and any slip with it)."""
        self.clamp_state = None
        self._slip = None

    def slip(self, mm_per_move: float = 0.0, deg_per_move: float = 0.0) -> None:
        """Make the current clamp slip from the next move on (see module docstring)."""
        if self.clamp_state is None:
            raise MotionError("no leg is clamped: nothing can slip")
        self._slip = Slip(mm_per_move, deg_per_move)
        # A fixed creep direction, perpendicular to the leg for a direction slip.
        axis = self._rng.normal(size=3)
        u = self.clamp_state.direction
        if self.clamp_state.constraint != Constraint.LENGTH:  # the direction part gives way
            axis -= (axis @ u) * u
        self._slip_axis = axis / np.linalg.norm(axis)

    def _creep(self) -> None:
        c, s = self.clamp_state, self._slip
        if c is None or s is None:
            return
        if c.constraint == Constraint.LENGTH:
            c = replace(c, length=c.length + s.mm_per_move)
        elif c.constraint == Constraint.DIRECTION:
            rot = Rotation.from_rotvec(np.deg2rad(s.deg_per_move) * self._slip_axis)
            c = replace(c, direction=rot.apply(c.direction))
        else:
            c = replace(c, point=c.point + s.mm_per_move * self._slip_axis)
        self.clamp_state = c

    # -- moving -----------------------------------------------------------------------------
    def _move(self, position: np.ndarray, rotation: np.ndarray) -> None:
        if self.before_move is not None:
            self.before_move()
        t = self.robot.move_to(position, rotation)
        self.moves += 1
        if self.on_move is not None:
            self.on_move(t)

    def violation_mm(self, position: np.ndarray, rotation: np.ndarray) -> float:
        """How far (mm) the pose breaks the current clamp's constraint (0 when unclamped)."""
        c = self.clamp_state
        if c is None:
            return 0.0
        k = c.leg - 1
        point = np.asarray(position, float) + np.asarray(rotation, float) @ self.robot.truth.b[k]
        v = point - self.robot.truth.a[k]
        if c.constraint == Constraint.LENGTH:
            return abs(float(np.linalg.norm(v)) - c.length)
        if c.constraint == Constraint.DIRECTION:
            return float(np.linalg.norm(v - (v @ c.direction) * c.direction))
        return float(np.linalg.norm(point - c.point))

    def move_to(self, position: np.ndarray, rotation: np.ndarray) -> None:
        """Move to a pose (P (3,) mm, R (3, 3)); refused if it breaks the clamp or the limits."""
        P, R = np.asarray(position, float), np.asarray(rotation, float)
        off = self.violation_mm(P, R)
        c = self.clamp_state
        if off > self.tolerance_mm and c is not None:  # no clamp: nothing to violate (off 0)
            raise MotionError(
                f"leg {c.leg} is clamped ({c.constraint}): that pose would move it {off:.3f} mm "
                "against the clamp — release the clamp or choose a pose that respects it"
            )
        if not self.sim.feasible(P, R):
            raise MotionError("that pose is outside the robot's joint limits or leg stroke")
        self._move(P, R)

    def next_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Move to a new random pose the current clamp allows (a free pose if none) and return
        it (P (3,) mm, R (3, 3), true). A slipping clamp creeps before the move."""
        self._creep()
        c = self.clamp_state
        try:
            if c is None:
                P, R = self.sim.free((1,), self._rng)
            elif c.constraint == Constraint.DIRECTION:
                P, R = self.sim.type_i(c.leg - 1, (1,), self._rng, direction=c.direction)
            elif c.constraint == Constraint.LENGTH:
                P, R = self.sim.type_iii(
                    c.leg - 1, (1,), self._rng, length=c.length, axis=c.direction
                )
            else:
                P, R = self.sim.type_ii(c.leg - 1, (1,), self._rng, point=c.point)
        except NoFeasiblePose:
            assert c is not None  # free poses about home always exist
            raise MotionError(
                f"leg {c.leg} is clamped ({c.constraint}) where no pose it allows is within the "
                "joint limits and the legs' stroke: release the clamp, move the platform nearer "
                "home and clamp again"
            ) from None
        # The drawn pose satisfies the (possibly crept) clamp exactly: bypass the tolerance
        # check only in so far as the clamp itself moved.
        self._move(P[0], R[0])
        return P[0], R[0]

    def move_near(
        self, position: np.ndarray, rotation: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Move as an operator follows a suggested pose (P (3,) mm, R (3, 3)): the rotation as
        given, the position the nearest one the clamp allows (on the true geometry: the clamp,
        not the operator, holds the constraint). Returns the pose reached; MotionError if it
        is outside the limits."""
        self._creep()
        c = self.clamp_state
        P, R = np.asarray(position, float), np.asarray(rotation, float)
        if c is not None:
            k = c.leg - 1
            rb = R @ self.robot.truth.b[k]
            a = self.robot.truth.a[k]
            if c.constraint == Constraint.DIRECTION:
                rho = float((P + rb - a) @ c.direction)
                P = a + rho * c.direction - rb
            elif c.constraint == Constraint.LENGTH:
                v = P + rb - a
                P = a + c.length * v / np.linalg.norm(v) - rb
            else:
                P = c.point - rb
        if not self.sim.feasible(P, R):
            raise MotionError("that pose is outside the robot's joint limits or leg stroke")
        self._move(P, R)
        return P, R

    def move_readings(self, readings: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Move as a controller jogs the legs to ``readings`` (6,) mm: the true pose whose legs
        have those readings on the true geometry (the hidden effects then show in what the
        encoders report). Refused while a leg is clamped, or outside the limits."""
        from hexcal.estimate.predict import LegModel, Poses

        if self.clamp_state is not None:
            raise MotionError(
                f"leg {self.clamp_state.leg} is clamped: release it before jogging the legs"
            )
        P0, R0 = self.robot.true_pose()
        model = LegModel(self.robot.truth)
        poses, closed = model.solve_poses(
            np.asarray(readings, float)[None], guess=Poses(P0[None], R0[None])
        )
        P, R = poses.position[0], poses.rotation[0]
        if not closed[0] or not self.sim.feasible(P, R):
            raise MotionError("those readings put the platform outside its joint limits or reach")
        self.robot.move_to(P, R)
        self.moves += 1
        return P, R

    def home(self) -> None:
        """Back to the robot's home pose (refused while a leg is clamped away from it)."""
        home = self.robot.truth.home
        R = Rotation.from_quat(home.quaternion, scalar_first=True).as_matrix()
        self.move_to(np.asarray(home.position, float), R)
