"""A robot's workspace: the constrained and free poses its platform can take, drawn at random
within the operator's ranges and the robot's limits. Used to propose poses (next best pose, the
guided session) and, with noise and hidden effects on top, by the simulator
(:mod:`hexcal.sim.simulate`). Pose generators are vectorised over any batch shape so that a
Monte-Carlo study draws all its trials at once.

Pose ranges (the paper does not state its own; these are the project's defaults, chosen as a
lab would move a hexapod of the Left Hand's size, legs about 210 mm):

* Type I (direction clamped): leg length uniform in ``home ± stroke_mm``; platform rotation
  vector uniform in the cube ``± tilt_deg`` about the home orientation.
* Type II (direction and length clamped): B_k fixed at its home position; rotations as Type I.
* Type III (length clamped): leg direction uniform in a cone of half-angle ``cone_deg`` about
  its home direction; rotations as Type I.
* Free: position uniform in ``home ± box_mm``; rotations as Type I.

Every pose is checked against the leg stroke (``robot.leg_range_mm`` on readings, when given)
and the joint-angle limits; infeasible draws are replaced.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.errors import RefusedError
from hexcal.model.robot import Robot

#: A pose drawer: ``draw(rng, shape) -> (P (*shape, 3) mm, R (*shape, 3, 3))``.
Draw = Callable[[np.random.Generator, tuple[int, ...]], tuple[np.ndarray, np.ndarray]]


class NoFeasiblePose(RefusedError, RuntimeError):
    """No pose of the kind asked for lies within the limits (for a clamp: none that the clamp
    allows), after 200 rounds of drawing."""


@dataclass(frozen=True)
class PoseRanges:
    """How far the simulated operator moves the platform (see module docstring)."""

    stroke_mm: float = 30.0
    tilt_deg: float = 15.0
    cone_deg: float = 12.0
    box_mm: tuple[float, float, float] = (20.0, 20.0, 20.0)


@dataclass(frozen=True)
class Limits:
    """Feasibility: joint angles from the base / platform normals, readings within stroke."""

    base_joint_deg: float = 50.0
    platform_joint_deg: float = 50.0
    reading_range_mm: tuple[float, float] | None = None


def _rotations(rng: np.random.Generator, tilt_deg: float, shape: tuple[int, ...]) -> np.ndarray:
    """Random rotation matrices (*shape, 3, 3), rotation vector uniform in ``± tilt_deg``."""
    rv = rng.uniform(-1.0, 1.0, (*shape, 3)) * np.deg2rad(tilt_deg)
    return Rotation.from_rotvec(rv.reshape(-1, 3)).as_matrix().reshape(*shape, 3, 3)


def _rotated_points(rotation: np.ndarray, b: np.ndarray) -> np.ndarray:
    """R b_k (..., 6, 3) for rotations (..., 3, 3) and the six platform points b (6, 3): one
    matrix product over all the rotations' rows (BLAS), four times faster than a stack."""
    rows = rotation.reshape(-1, 3) @ b.T  # (... 3, 6)
    return np.swapaxes(rows.reshape(*rotation.shape[:-2], 3, len(b)), -1, -2)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _cone(
    rng: np.random.Generator, axis: np.ndarray, half_deg: float, shape: tuple[int, ...]
) -> np.ndarray:
    """Unit vectors (*shape, 3) uniform in solid angle within ``half_deg`` of ``axis`` (3,)."""
    cos_max = np.cos(np.deg2rad(half_deg))
    z = rng.uniform(cos_max, 1.0, shape)
    phi = rng.uniform(0.0, 2 * np.pi, shape)
    s = np.sqrt(1.0 - z**2)
    local = np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)
    # Rotation taking +z onto the axis; align_vectors is scipy's, no hand-rolled Rodrigues.
    align, _ = Rotation.align_vectors(np.atleast_2d(axis), [[0.0, 0.0, 1.0]])
    return local @ align.as_matrix().T


@dataclass
class Workspace:
    """Where a robot's platform can go: feasible poses of each kind (Type I, II, III, free)
    drawn about its home pose, and the geometric leg lengths of a pose.

    ``robot`` holds the geometry (its offsets are the offsets). The home pose is
    ``robot.home``. All arrays are in mm; rotations are (…, 3, 3) matrices built by
    :class:`~scipy.spatial.transform.Rotation`.
    """

    robot: Robot
    ranges: PoseRanges = field(default_factory=PoseRanges)
    limits: Limits = field(default_factory=Limits)

    @property
    def home_position(self) -> np.ndarray:
        return np.asarray(self.robot.home.position, float)

    @property
    def home_rotation(self) -> np.ndarray:
        return Rotation.from_quat(self.robot.home.quaternion, scalar_first=True).as_matrix()

    def home_leg(self, k: int) -> tuple[np.ndarray, float]:
        """Leg k (0-based) at home: unit direction (3,) and geometric length, mm."""
        v = self.home_position + self.home_rotation @ self.robot.b[k] - self.robot.a[k]
        return _unit(v), float(np.linalg.norm(v))

    # -- feasibility -------------------------------------------------------------------------
    def feasible(self, position: np.ndarray, rotation: np.ndarray) -> np.ndarray:
        """Mask (...,) of poses within joint-angle limits and reading stroke for all six legs."""
        a, b = self.robot.a, self.robot.b
        v = position[..., None, :] + _rotated_points(rotation, b) - a
        length = np.linalg.norm(v, axis=-1)
        n = v / length[..., None]
        ok = n[..., 2] >= np.cos(np.deg2rad(self.limits.base_joint_deg))
        plat_z = rotation[..., :, 2]
        ok &= (n @ plat_z[..., None])[..., 0] >= np.cos(np.deg2rad(self.limits.platform_joint_deg))
        rng_mm = self.limits.reading_range_mm or (
            tuple(self.robot.leg_range_mm) if self.robot.leg_range_mm else None
        )
        if rng_mm is not None:
            reading = length - self.robot.offsets
            ok &= (reading >= rng_mm[0]) & (reading <= rng_mm[1])
        return ok.all(axis=-1)

    def _fill(
        self, rng: np.random.Generator, shape: tuple[int, ...], draw: Draw
    ) -> tuple[np.ndarray, np.ndarray]:
        """Draw poses with ``draw(rng, shape) -> (P, R)`` until every slot is feasible."""
        p, r = draw(rng, shape)
        bad = ~self.feasible(p, r)
        for _ in range(200):
            if not bad.any():
                return p, r
            pn, rn = draw(rng, (int(bad.sum()),))
            p[bad], r[bad] = pn, rn
            bad[bad] = ~self.feasible(pn, rn)
        raise NoFeasiblePose("could not draw feasible poses: widen the limits or shrink the ranges")

    # -- pose generators (true poses) ----------------------------------------------------------
    def type_i(
        self,
        k: int,
        shape: tuple[int, ...],
        rng: np.random.Generator,
        direction: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Type I poses of leg k (0-based): its direction clamped, length free. (P, R)."""
        u, l0 = self.home_leg(k)
        u = u if direction is None else _unit(np.asarray(direction, float))
        a, b = self.robot.a[k], self.robot.b[k]
        s = self.ranges.stroke_mm

        def draw(g: np.random.Generator, sh: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
            r = _rotations(g, self.ranges.tilt_deg, sh) @ self.home_rotation
            length = g.uniform(l0 - s, l0 + s, sh)
            return a + length[..., None] * u - r @ b, r

        return self._fill(rng, shape, draw)

    def type_ii(
        self,
        k: int,
        shape: tuple[int, ...],
        rng: np.random.Generator,
        point: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Type II poses of leg k: direction and length clamped, B_k fixed in space (at
        ``point`` (3,) mm; default: where it is at home). (P, R)."""
        u, l0 = self.home_leg(k)
        c = self.robot.a[k] + l0 * u if point is None else np.asarray(point, float)
        b = self.robot.b[k]

        def draw(g: np.random.Generator, sh: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
            r = _rotations(g, self.ranges.tilt_deg, sh) @ self.home_rotation
            return c - r @ b, r

        return self._fill(rng, shape, draw)

    def type_iii(
        self,
        k: int,
        shape: tuple[int, ...],
        rng: np.random.Generator,
        length: float | None = None,
        axis: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Type III poses of leg k: length clamped (at ``length`` mm, default its home length),
        direction free within the cone about ``axis`` (default the home direction). (P, R)."""
        u0, l0 = self.home_leg(k)
        l0 = l0 if length is None else float(length)
        u0 = u0 if axis is None else _unit(np.asarray(axis, float))
        a, b = self.robot.a[k], self.robot.b[k]

        def draw(g: np.random.Generator, sh: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
            r = _rotations(g, self.ranges.tilt_deg, sh) @ self.home_rotation
            u = _cone(g, u0, self.ranges.cone_deg, sh)
            return a + l0 * u - r @ b, r

        return self._fill(rng, shape, draw)

    def free(
        self, shape: tuple[int, ...], rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """Free poses: position in the box about home, rotation as the others. (P, R)."""
        box = np.asarray(self.ranges.box_mm, float)

        def draw(g: np.random.Generator, sh: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
            r = _rotations(g, self.ranges.tilt_deg, sh) @ self.home_rotation
            return self.home_position + g.uniform(-1, 1, (*sh, 3)) * box, r

        return self._fill(rng, shape, draw)

    # -- lengths ---------------------------------------------------------------------------------
    def true_lengths(self, position: np.ndarray, rotation: np.ndarray) -> np.ndarray:
        """Geometric lengths (..., 6) mm of this geometry at the poses."""
        v = position[..., None, :] + _rotated_points(rotation, self.robot.b) - self.robot.a
        return np.linalg.norm(v, axis=-1)
