"""``calibrated.json``: the calibrated model as one file (docs/formats.md, "calibrated.json").

The file is a robot.json with one more key, ``calibration``: the fitted geometry sits where
robot.json has it (``base_points``, ``platform_points``, ``leg_offsets`` and every other key of
the design), so any reader of robot.json gets the calibrated geometry; ``calibration`` holds the
model's name, every effect with its parameters (value, σ, unit), the noise it was fitted with,
its fit statistics, the pose accuracy it reaches on held-out poses, and the provenance (hexcal
version, SHA-256 of the inputs, date, pose count). ``calibration.format_version`` is checked:
a file from a newer hexcal is refused, not misread.

:func:`load_model` reads either file: a plain robot.json is the model with no effects (the
drawing), so ``hexcal validate`` and ``hexcal predict`` take both.
"""

from __future__ import annotations

import hashlib
from datetime import datetime, timezone
from pathlib import Path
from typing import Annotated, Any, Final, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from hexcal import __version__
from hexcal.effects import get_effect
from hexcal.effects.priors import check_priors
from hexcal.estimate.predict import LegModel
from hexcal.io.fileio import write_text_atomic
from hexcal.io.safe_read import Count, NotBool
from hexcal.io.validation import format_validation_error, shown_value
from hexcal.model.instruments import Instruments
from hexcal.model.robot import Robot, RobotFileError, json_text, read_robot_json
from hexcal.vocabulary import ModelKindField

#: Largest magnitude of a fitted parameter or its σ, in its unit (ppm, mm, µm/N...).
MAX_PARAMETER = 1e12
#: A fit or accuracy statistic (RMS, percentile, χ²/dof...): finite, ≥ 0.
Statistic = Annotated[float, Field(ge=0, le=MAX_PARAMETER, allow_inf_nan=False), NotBool]

FORMAT: Final = "hexcal-calibrated-model"
FORMAT_VERSION = 1


class ParameterValue(BaseModel):
    """One fitted parameter in its unit; ``sigma`` None when the data did not determine it."""

    model_config = ConfigDict(extra="forbid")
    name: str
    value: Annotated[float, NotBool] = Field(
        ge=-MAX_PARAMETER, le=MAX_PARAMETER, allow_inf_nan=False
    )
    sigma: Annotated[float, NotBool] | None = Field(
        None, ge=0, le=MAX_PARAMETER, allow_inf_nan=False
    )
    unit: str


class EffectRecord(BaseModel):
    """One catalogue effect of the model and its fitted parameters."""

    model_config = ConfigDict(extra="forbid")
    name: str
    parameters: list[ParameterValue]
    physics: str = ""


class FitRecord(BaseModel):
    """How the model fits the poses it was calibrated on (leg lengths, mm)."""

    model_config = ConfigDict(extra="forbid")
    poses: Count
    chi2_per_dof: Statistic | None = None
    rms_mm: Statistic | None = Field(
        None, description="leg-length residual RMS on the fitted poses"
    )
    heldout_rms_mm: Statistic | None = Field(
        None, description="leg-length residual RMS on held-out poses (5 random folds)"
    )
    noise_floor_mm: Statistic | None = Field(
        None, description="the leg-length RMS the instruments' noise alone gives"
    )
    clamps: str | None = Field(None, description="whether the clamps' constraints were used")


class AccuracyRecord(BaseModel):
    """Pose accuracy: the pose computed from the six readings against the tracker's, at the
    platform origin; errors in mm and degrees."""

    model_config = ConfigDict(extra="forbid")
    model: str = Field(description="e.g. 'design', 'Model 42', 'Model 42 + gain'")
    heldout: bool = Field(description="each pose predicted by a fit that did not see it")
    poses: Count
    position_rms_mm: Statistic | None = None
    position_p95_mm: Statistic | None = None
    position_max_mm: Statistic | None = None
    orientation_rms_deg: Statistic | None = None
    orientation_p95_deg: Statistic | None = None
    orientation_max_deg: Statistic | None = None
    leg_rms_mm: Statistic | None = None
    floor_position_rms_mm: Statistic | None = Field(
        None, description="position RMS the instruments' noise alone gives"
    )
    floor_orientation_rms_deg: Statistic | None = None
    failed: Count = Field(0, description="poses whose readings no pose closes")


class InputRecord(BaseModel):
    model_config = ConfigDict(extra="forbid")
    role: str
    name: str
    sha256: str


class Provenance(BaseModel):
    model_config = ConfigDict(extra="forbid")
    hexcal_version: str = __version__
    created: datetime = Field(default_factory=lambda: datetime.now(timezone.utc))
    poses: Count
    inputs: list[InputRecord] = Field(default_factory=list)


class CalibrationBlock(BaseModel):
    """The ``calibration`` key of calibrated.json."""

    model_config = ConfigDict(extra="forbid")
    format: Literal["hexcal-calibrated-model"] = FORMAT
    format_version: Annotated[int, NotBool] = Field(FORMAT_VERSION, ge=1, le=FORMAT_VERSION)
    model: str = Field(description="e.g. 'Model 42 + gain + backlash'")
    kind: ModelKindField
    effects: list[EffectRecord] = Field(default_factory=list)
    noise: Instruments | None = Field(None, description="the noise the model was fitted with")
    noise_source: str = ""
    fit: FitRecord
    accuracy: list[AccuracyRecord] = Field(
        default_factory=list,
        description="pose accuracy of the design, the geometry alone and each effect added",
    )
    provenance: Provenance


class CalibratedRobot(Robot):
    """calibrated.json: a robot.json whose geometry is calibrated, plus ``calibration``."""

    calibration: CalibrationBlock

    def leg_model(self) -> LegModel:
        """The model as a predictor (geometry and effects)."""
        effects = tuple(e.name for e in self.calibration.effects)
        values = [p.value for e in self.calibration.effects for p in e.parameters]
        return LegModel(self.plain_robot(), effects, np.array(values, float))

    def plain_robot(self) -> Robot:
        """The geometry as a plain robot.json (the calibration block left out)."""
        return Robot.model_validate(self.model_dump(exclude={"calibration"}, exclude_none=True))

    def to_json(self) -> str:
        """calibrated.json text (indent 2); NaN or infinity anywhere is refused, not written."""
        return json_text(self.model_dump(mode="json", exclude_none=True))


def effect_records(model: LegModel, sigmas: dict[str, float] | None = None) -> list[EffectRecord]:
    """The model's effects with their values, in spec units; ``sigmas`` by parameter name."""
    out, i = [], 0
    for e in model.effects:
        eff = get_effect(e)
        params = []
        for spec in eff.params(model.robot):
            s = None if sigmas is None else sigmas.get(spec.name)
            sigma = float(s) if s is not None and np.isfinite(s) else None
            params.append(
                ParameterValue(
                    name=spec.name, value=float(model.values[i]), sigma=sigma, unit=spec.unit
                )
            )
            i += 1
        out.append(EffectRecord(name=e, parameters=params, physics=eff.physics))
    return out


def sha256_of(path: str | Path) -> str:
    h = hashlib.sha256()
    with Path(path).open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def input_records(inputs: dict[str, Path | None]) -> list[InputRecord]:
    """{role: path} → records with each file's SHA-256 (missing paths left out)."""
    return [
        InputRecord(role=role, name=Path(p).name, sha256=sha256_of(p))
        for role, p in inputs.items()
        if p is not None and Path(p).is_file()
    ]


def is_calibrated(data: Any) -> bool:
    return isinstance(data, dict) and isinstance(data.get("calibration"), dict)


def parse_model(data: Any, where: str) -> CalibratedRobot | Robot:
    """A calibrated.json object or a plain robot.json object, validated; errors name ``where``."""
    if is_calibrated(data):
        block = data["calibration"]
        if block.get("format") != FORMAT:
            raise RobotFileError(
                f"{where}: field calibration.format: expected {FORMAT!r}, got "
                f"{shown_value(block.get('format'))}; this is not a hexcal calibrated model"
            )
        version = block.get("format_version")
        if isinstance(version, bool) or not isinstance(version, int) or version < 1:
            raise RobotFileError(
                f"{where}: field calibration.format_version: {shown_value(version)} is not a "
                f"format version (an integer from 1; this hexcal writes {FORMAT_VERSION})"
            )
        if version > FORMAT_VERSION:
            raise RobotFileError(
                f"{where}: calibrated model format version {shown_value(version)}; this hexcal "
                f"{__version__} reads version {FORMAT_VERSION}: upgrade hexcal to read it"
            )
        cls: type[Robot] = CalibratedRobot
    else:
        cls = Robot
    try:
        robot = cls.model_validate(data)
    except ValidationError as exc:
        raise RobotFileError(format_validation_error(exc, where, data)) from None
    try:
        check_priors(robot, where)
    except ValueError as exc:
        raise RobotFileError(str(exc)) from None
    if isinstance(robot, CalibratedRobot):
        try:
            robot.leg_model()
        except ValidationError as exc:
            raise RobotFileError(format_validation_error(exc, where)) from None
        except ValueError as exc:
            raise RobotFileError(f"{where}: field calibration.effects: {exc}") from None
    return robot


def load_model(path: str | Path) -> CalibratedRobot | Robot:
    """Read calibrated.json (or a plain robot.json: the model with no effects)."""
    return parse_model(read_robot_json(path), str(path))


def load_robot(path: str | Path) -> Robot:
    """Read robot.json (or a calibrated.json: its geometry, the calibration block validated
    and left out); errors name the file and the field and say what to fix."""
    model = load_model(path)
    return model.plain_robot() if isinstance(model, CalibratedRobot) else model


def leg_model_of(robot: Robot) -> LegModel:
    """The predictor of a loaded model file: its effects when calibrated, none for a drawing."""
    if isinstance(robot, CalibratedRobot):
        return robot.leg_model()
    return LegModel(robot)


def model_label(robot: Robot) -> str:
    if isinstance(robot, CalibratedRobot):
        return robot.calibration.model
    return "design (robot.json, no calibration)"


def save_model(model: CalibratedRobot, path: str | Path) -> None:
    """Write calibrated.json atomically."""
    write_text_atomic(path, model.to_json())
