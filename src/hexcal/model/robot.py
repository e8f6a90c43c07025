"""The robot description: six base points, six platform points, six leg offsets (robot.json).

Leg k joins base point ``a_k`` (base / measurement frame) to platform point ``b_k`` (platform
frame). Its geometric length is ``|P + R b_k - a_k|`` and, in the ideal model, equals the encoder
reading plus ``offset_k``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
)

from hexcal.errors import InputError, RefusedError
from hexcal.io.fileio import write_text_atomic
from hexcal.io.safe_read import MAX_COORDINATE_MM, Millimetres, NotBool, QuaternionPart, read_json
from hexcal.io.validation import format_validation_error

#: A point or vector in mm, each coordinate finite and within ±MAX_COORDINATE_MM (1 km).
Vec3 = Annotated[list[Millimetres], Field(min_length=3, max_length=3)]
#: A number that JSON's true/false may not stand for.
Number = Annotated[float, NotBool]
#: Largest leadscrew pitch, mm, and platform mass, kg, robot.json may state.
MAX_PITCH_MM = 1e3
MAX_MASS_KG = 1e6
#: Largest backlash dead band robot.json may state, mm.
MAX_DEADBAND_MM = 1e3
#: Largest bound of a plausible range, in the parameter's unit (as calibrated.json's values).
MAX_PRIOR = 1e12
#: A plausible range [lo, hi] in a parameter's unit.
Range = Annotated[
    list[Annotated[float, Field(ge=-MAX_PRIOR, le=MAX_PRIOR, allow_inf_nan=False), NotBool]],
    Field(min_length=2, max_length=2),
]


class RobotFileError(InputError):
    """robot.json could not be read; the message names the file and the field."""


class GeometryOutOfRange(RefusedError, ValueError):
    """A computed geometry (a fit's) is not finite or beyond the ±1 km any robot file may hold:
    the computation diverged; nothing is wrong with the user's files."""


class Home(BaseModel):
    """The platform's home pose: position (3,) mm, unit quaternion (4,) scalar first."""

    model_config = ConfigDict(extra="allow")
    position: Vec3 = [0.0, 0.0, 0.0]
    quaternion: Annotated[list[QuaternionPart], Field(min_length=4, max_length=4)] = [
        1.0,
        0.0,
        0.0,
        0.0,
    ]

    @field_validator("quaternion")
    @classmethod
    def _unit(cls, q: list[float]) -> list[float]:
        n = float(np.linalg.norm(q))
        if abs(n - 1.0) > 1e-3:
            raise ValueError(
                f"quaternion norm is {n:.6f}, expected 1 (scalar first: qw, qx, qy, qz)"
            )
        return q


class ZeroStep(BaseModel):
    """A change of one leg's encoder zero during a session (lost counts, a re-home): from
    ``t_s`` (s, the session's clock) on, leg ``leg`` reads differently for the same length.
    Located by ``hexcal diagnose`` (its change-point search), or stated in robot.json."""

    model_config = ConfigDict(extra="forbid")
    leg: int = Field(ge=1, le=6)
    t_s: float = Field(allow_inf_nan=False)


class FrameStep(BaseModel):
    """A rigid move of the tracker (or of the robot's base under it) during a session: from
    ``t_s`` (s, the session's clock) on, every pose is measured in a frame moved by a small
    rotation and translation. Located by ``hexcal diagnose`` (its search for a rigid move of
    every leg at one pose), or stated in robot.json."""

    model_config = ConfigDict(extra="forbid")
    t_s: float = Field(allow_inf_nan=False)


class Robot(BaseModel):
    """A Gough platform's geometry as in robot.json (docs/formats.md). Unknown keys are kept."""

    model_config = ConfigDict(extra="allow")
    name: str = "robot"
    units: str = "mm"
    base_points: Annotated[list[Vec3], Field(min_length=6, max_length=6)]
    platform_points: Annotated[list[Vec3], Field(min_length=6, max_length=6)]
    leg_offsets: Annotated[list[Millimetres], Field(min_length=6, max_length=6)] = [0.0] * 6
    home: Home = Home()
    #: Lead of the legs' screws, mm per turn.
    leadscrew_pitch_mm: Number | None = Field(None, gt=0, le=MAX_PITCH_MM, allow_inf_nan=False)
    #: Moving mass carried by the legs, kg.
    platform_mass_kg: Number | None = Field(None, gt=0, le=MAX_MASS_KG, allow_inf_nan=False)
    #: Where the weight acts, mm, platform frame (default: the platform origin).
    platform_com_mm: Vec3 | None = None
    #: The stroke as limits on the encoder readings, [min, max] mm.
    leg_range_mm: Annotated[list[Millimetres], Field(min_length=2, max_length=2)] | None = None
    #: Changes of a leg's encoder zero during the session (at most one per leg), for the
    #: ``zero_step`` effect.
    zero_steps: Annotated[list[ZeroStep], Field(max_length=6)] | None = None
    #: Rigid moves of the tracker (or the base) during the session, for the ``frame_step``
    #: effect.
    frame_steps: Annotated[list[FrameStep], Field(max_length=3)] | None = None
    #: Half-angle of each joint's cone about the leg's direction at home, deg (both ends).
    joint_limit_deg: Number | None = Field(None, gt=0, le=180, allow_inf_nan=False)
    #: Plausible ranges replacing the catalogue's: by effect (``gain``) or by parameter's full
    #: name (``gain.g1``, which wins), in the parameter's unit; offsets relative to the design.
    plausible: dict[str, Range] | None = None
    #: The smallest change of a leg's reading that counts as a move for backlash, mm (default:
    #: 4·√2·σ of the stated encoder noise, set by the fit; 0.02 mm when the noise is unknown).
    backlash_deadband_mm: Number | None = Field(None, gt=0, le=MAX_DEADBAND_MM, allow_inf_nan=False)
    #: The first (fixed) axis of each base U-joint, a direction in the base frame (any length
    #: but zero), for the ``ujoint`` effect; default: horizontal and across the leg at home.
    ujoint_axes: Annotated[list[Vec3], Field(min_length=6, max_length=6)] | None = None
    #: The first axis of each platform joint, fixed in the platform, a direction in the
    #: platform frame, for the ``balljoint`` effect; default: horizontal in the platform frame
    #: and across the leg at home.
    balljoint_axes: Annotated[list[Vec3], Field(min_length=6, max_length=6)] | None = None

    @field_validator("units")
    @classmethod
    def _mm(cls, u: str) -> str:
        if u != "mm":
            raise ValueError(f"units must be 'mm' (got {u!r}); convert the file to millimetres")
        return u

    @field_validator("leg_range_mm")
    @classmethod
    def _ordered(cls, r: list[float] | None) -> list[float] | None:
        if r is not None and not r[0] < r[1]:
            raise ValueError(f"leg_range_mm is [min, max] with min < max (got {r})")
        return r

    @field_validator("ujoint_axes", "balljoint_axes")
    @classmethod
    def _directions(cls, axes: list[list[float]] | None) -> list[list[float]] | None:
        if axes is not None:
            for k, axis in enumerate(axes, start=1):
                if not float(np.linalg.norm(axis)) > 1e-9:
                    raise ValueError(f"joint {k}'s axis is {axis}: give a direction, not zero")
        return axes

    @field_validator("zero_steps")
    @classmethod
    def _one_per_leg(cls, steps: list[ZeroStep] | None) -> list[ZeroStep] | None:
        legs = [s.leg for s in steps or []]
        if len(set(legs)) != len(legs):
            raise ValueError(f"at most one zero step per leg (legs {legs})")
        return steps

    @field_validator("plausible")
    @classmethod
    def _priors(cls, table: dict[str, list[float]] | None) -> dict[str, list[float]] | None:
        if not table:
            return table
        for key, (lo, hi) in table.items():
            if not lo < hi:
                raise ValueError(f"{key} is [low, high] with low < high (got [{lo:g}, {hi:g}])")
        return table

    @property
    def a(self) -> np.ndarray:
        """Base points, (6, 3) mm, base frame."""
        return np.asarray(self.base_points, dtype=float)

    @property
    def b(self) -> np.ndarray:
        """Platform points, (6, 3) mm, platform frame."""
        return np.asarray(self.platform_points, dtype=float)

    @property
    def offsets(self) -> np.ndarray:
        """Leg offsets, (6,) mm: geometric length = reading + offset."""
        return np.asarray(self.leg_offsets, dtype=float)

    def with_geometry(
        self, a: np.ndarray, b: np.ndarray, offsets: np.ndarray | None = None, **extra: object
    ) -> Robot:
        """A copy with new points (6, 3) mm and offsets (6,) mm; other keys carried over."""
        data = self.model_dump(exclude_none=True)
        data["base_points"] = np.asarray(a, float).tolist()
        data["platform_points"] = np.asarray(b, float).tolist()
        if offsets is not None:
            data["leg_offsets"] = np.asarray(offsets, float).tolist()
        data.update(extra)
        numbers = np.concatenate([np.ravel(a), np.ravel(b), np.ravel(data["leg_offsets"])])
        worst = float(np.max(np.abs(numbers))) if np.all(np.isfinite(numbers)) else np.inf
        if not worst <= MAX_COORDINATE_MM:
            raise GeometryOutOfRange(
                "the geometry is not finite"
                if not np.isfinite(worst)
                else f"a coordinate or offset reached {worst:.3g} mm, beyond the ±1 km any robot "
                "file may hold"
            )
        try:
            return Robot.model_validate(data)
        except ValidationError as exc:  # e.g. a fit that diverged to NaN or beyond 1 km
            raise GeometryOutOfRange(
                format_validation_error(exc, "computed geometry", data)
            ) from None

    def to_json(self) -> str:
        """robot.json text (indent 2); absent optional keys stay absent. An unknown key
        holding NaN or infinity (set in code) is refused: JSON has no such numbers."""
        return json_text(self.model_dump(exclude_none=True))


def json_text(data: Any) -> str:
    """JSON text (indent 2) of a robot file's content; NaN or infinity is refused."""
    try:
        return json.dumps(data, indent=2, allow_nan=False) + "\n"
    except ValueError:
        raise RobotFileError(
            "the robot holds a NaN or infinite number (in an unknown key); it is not written"
        ) from None


def read_robot_json(path: str | Path) -> object:
    """The JSON object of a robot file (robot.json or calibrated.json), within the limits of
    :mod:`hexcal.io.safe_read`; errors name the file and the line or field."""
    return read_json(path, "robot", RobotFileError)


def save_robot(robot: Robot, path: str | Path) -> None:
    """Write robot.json atomically."""
    write_text_atomic(path, robot.to_json())
