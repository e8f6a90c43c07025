"""Simulated Gough platform: constrained and free poses, measurement noise, hooks for effects.

This is the robot that mock_hw replays and that the tests and the study calibrate. Pose
generators are vectorised over any batch shape so that a Monte-Carlo study draws all its trials
at once.

The poses are drawn by :class:`~hexcal.model.workspace.Workspace` (its ranges and limits are
described there); the simulator adds the instruments' noise and the hidden effects.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal, overload

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.model.workspace import Limits, PoseRanges, Workspace

__all__ = [
    "LengthEffect",
    "Limits",
    "NoiseModel",
    "PoseContext",
    "PoseRanges",
    "Simulator",
    "Workspace",
]

#: A hidden physical effect: extra geometric length (..., 6) mm for the given readings
#: (..., 6) mm and the pose context. ``length = reading + offset + sum(effects)``.
LengthEffect = Callable[[np.ndarray, "PoseContext"], np.ndarray]


@dataclass(frozen=True)
class PoseContext:
    """What an effect may depend on, for a batch of N poses in recording order."""

    position: np.ndarray  #: (N, 3) mm, true
    rotation: np.ndarray  #: (N, 3, 3), true
    t: np.ndarray  #: (N,) s
    temperature: np.ndarray  #: (N,) degC


@dataclass(frozen=True)
class NoiseModel:
    """Measurement noise. ``gaussian``: each value is a standard deviation. ``uniform`` (the
    paper's): each is the half-width of a uniform law on every coordinate.

    Orientation noise is a small rotation about each axis of the platform frame.
    """

    position_mm: float = 0.0
    orientation_deg: float = 0.0
    reading_mm: float = 0.0
    kind: Literal["gaussian", "uniform"] = "gaussian"

    def _draw(self, rng: np.random.Generator, scale: float, shape: tuple[int, ...]) -> np.ndarray:
        if scale == 0.0:
            return np.zeros(shape)
        if self.kind == "uniform":
            return rng.uniform(-scale, scale, shape)
        return rng.normal(0.0, scale, shape)

    @property
    def _factor(self) -> float:
        # Standard deviation of one coordinate per unit of the stated value.
        return 1.0 / np.sqrt(3.0) if self.kind == "uniform" else 1.0

    @property
    def sigma_position_mm(self) -> float:
        return self.position_mm * self._factor

    @property
    def sigma_orientation_rad(self) -> float:
        return np.deg2rad(self.orientation_deg) * self._factor

    @property
    def sigma_reading_mm(self) -> float:
        return self.reading_mm * self._factor

    @overload
    def apply(
        self,
        rng: np.random.Generator,
        position: np.ndarray,
        rotation: np.ndarray,
        readings: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...

    @overload
    def apply(
        self,
        rng: np.random.Generator,
        position: np.ndarray,
        rotation: np.ndarray,
        readings: None = None,
    ) -> tuple[np.ndarray, np.ndarray, None]: ...

    def apply(
        self,
        rng: np.random.Generator,
        position: np.ndarray,
        rotation: np.ndarray,
        readings: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Measured copies: position (..., 3) mm, rotation (..., 3, 3), readings (..., K) mm."""
        shape = position.shape[:-1]
        p = position + self._draw(rng, self.position_mm, position.shape)
        dtheta = self._draw(rng, np.deg2rad(self.orientation_deg), (*shape, 3))
        d = Rotation.from_rotvec(dtheta.reshape(-1, 3)).as_matrix().reshape(*shape, 3, 3)
        r = rotation @ d  # body-frame perturbation: R_meas = R exp([dtheta]x)
        rho = (
            None
            if readings is None
            else readings + self._draw(rng, self.reading_mm, readings.shape)
        )
        return p, r, rho


@dataclass
class Simulator(Workspace):
    """A robot with a true geometry, limits, noise and optional hidden effects: its
    :class:`~hexcal.model.workspace.Workspace` (the poses it can take), and what the instruments
    report at those poses.

    ``robot`` holds the true geometry (its offsets are the true offsets).
    """

    noise: NoiseModel = field(default_factory=NoiseModel)
    effects: Sequence[LengthEffect] = ()

    # -- readings -------------------------------------------------------------------------------
    def readings(
        self, position: np.ndarray, rotation: np.ndarray, context: PoseContext | None = None
    ) -> np.ndarray:
        """Noise-free encoder readings (..., 6) mm: the r solving ``r + offset + effects(r) = L``.

        Effects are small against the stroke, so a fixed-point iteration converges in a few
        steps; it runs until the readings stop changing (1e-12 mm).
        """
        length = self.true_lengths(position, rotation)
        rho = length - self.robot.offsets
        if not self.effects:
            return rho
        if context is None:
            raise ValueError("effects need a PoseContext (time, temperature, true pose)")
        for _ in range(100):
            extra = sum(e(rho, context) for e in self.effects)
            new = length - self.robot.offsets - extra
            if np.max(np.abs(new - rho)) < 1e-12:
                return new
            rho = new
        return rho

    def measure(
        self,
        rng: np.random.Generator,
        position: np.ndarray,
        rotation: np.ndarray,
        context: PoseContext | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What the instruments report for true poses: (P (…,3) mm, R (…,3,3), readings (…,6) mm)."""
        return self.noise.apply(rng, position, rotation, self.readings(position, rotation, context))
