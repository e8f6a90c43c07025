"""``calibrated.json``: the calibrated model as one file (docs/formats.md, "calibrated.json").

The file is a robot.json with one more key, ``calibration``: the fitted geometry sits where
robot.json has it (``base_points``, ``platform_points``, ``leg_offsets`` and every other key of
the design), so any reader of robot.json gets the calibrated geometry; ``calibration`` holds the
model's name, every effect with its parameters (value, σ, unit), the noise it was fitted with,
its fit statistics, the pose accuracy it reaches on held-out poses, and the provenance (hexcal
version, SHA-256 of the inputs, date, pose count). ``calibration.format_version`` is checked:
a file from a newer hexcal is refused, not misread. Version 2 adds, to each effect from outside
hexcal's catalogue, its ``source`` (the package and version, or the file's SHA-256); hexcal
writes version 1 when every effect is the catalogue's, so older readers still read those files.
Version 3 adds the fitted poses' ``fingerprint`` (their values, :mod:`hexcal.io.pose_fingerprint`)
and the ``uncertainty`` terms beyond the parameters and the readings.
An effect the file names but this process has not loaded is refused, naming what to install or
pass (:func:`parse_model`); nothing in the file is ever executed.

:func:`load_model` reads either file: a plain robot.json is the model with no effects (the
drawing), so ``hexcal validate`` and ``hexcal predict`` take both.
"""

from __future__ import annotations

import hashlib
from datetime import datetime, timezone
from pathlib import Path
from typing import Annotated, Any, Final, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from hexcal import __version__
from hexcal.effects import CATALOGUE, EffectSource, get_effect
from hexcal.effects.plugins import failure_of
from hexcal.effects.priors import check_priors
from hexcal.estimate.predict import LegModel
from hexcal.estimate.uncertainty import (
    SESSION_DOF,
    ParameterCovariance,
    SessionTerms,
    excess_mm,
    model_parameter_names,
)
from hexcal.io.fileio import write_text_atomic
from hexcal.io.pose_fingerprint import (
    KEY_HEX,
    QUANTUM_MM,
    QUANTUM_RAD,
    Fingerprint,
    fingerprint,
    shared_rows,
)
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
#: The newest format version this hexcal reads and writes. 1: the catalogue's effects only;
#: 2 adds ``covariance`` and ``fitted_poses`` (both optional), and an effect from outside the
#: catalogue records its ``source``; 3 adds ``fitted_poses.fingerprint`` and ``uncertainty``.
#: Version 1 and 2 files are still read.
FORMAT_VERSION = 3
#: The version a file needs when an effect records its source.
SOURCE_VERSION = 2
#: The version a file needs when it holds a fingerprint or uncertainty terms.
FINGERPRINT_VERSION = 3
#: Largest magnitude of a covariance entry: the square of :data:`MAX_PARAMETER`.
MAX_COVARIANCE = MAX_PARAMETER**2


#: The records' settings. Their validators are built when first used (reading or writing a
#: calibrated.json), not when this module is imported: ``hexcal calibrate`` without ``--out``
#: reads robot.json through this module and never needs them (7 ms of its start).
_RECORD = ConfigDict(extra="forbid", defer_build=True)


class ParameterValue(BaseModel):
    """One fitted parameter in its unit; ``sigma`` None when the data did not determine it."""

    model_config = _RECORD
    name: str
    value: Annotated[float, NotBool] = Field(
        ge=-MAX_PARAMETER, le=MAX_PARAMETER, allow_inf_nan=False
    )
    sigma: Annotated[float, NotBool] | None = Field(
        None, ge=0, le=MAX_PARAMETER, allow_inf_nan=False
    )
    unit: str


class SourceRecord(BaseModel):
    """Where an effect from outside the catalogue came from (format version 2): an installed
    ``package`` (name, version, entry point), a ``file`` given with ``--effects`` (its name and
    the SHA-256 of its bytes), or a ``module`` of the program that wrote the file."""

    model_config = _RECORD
    kind: Literal["package", "file", "module"]
    package: str | None = Field(None, min_length=1, max_length=200)
    version: str | None = Field(None, max_length=100)
    entry_point: str | None = Field(None, max_length=400)
    file: str | None = Field(None, min_length=1, max_length=400)
    sha256: str | None = Field(None, pattern=r"^[0-9a-f]{64}$")
    module: str | None = Field(None, min_length=1, max_length=400)

    @classmethod
    def of(cls, source: EffectSource) -> SourceRecord | None:
        """The record of a registered effect's source (None for the catalogue's own)."""
        if source.kind == "catalogue":
            return None
        fields = ("package", "version", "entry_point", "file", "sha256", "module")
        return cls(kind=source.kind, **{f: getattr(source, f) or None for f in fields})

    def effect_source(self) -> EffectSource:
        return EffectSource(
            self.kind,
            package=self.package or "",
            version=self.version or "",
            entry_point=self.entry_point or "",
            file=self.file or "",
            sha256=self.sha256 or "",
            module=self.module or "",
        )


class EffectRecord(BaseModel):
    """One effect of the model and its fitted parameters; ``source`` when it is not one of
    hexcal's catalogue."""

    model_config = _RECORD
    name: str
    parameters: list[ParameterValue]
    physics: str = ""
    source: SourceRecord | None = None


class FitRecord(BaseModel):
    """How the model fits the poses it was calibrated on (leg lengths, mm)."""

    model_config = _RECORD
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

    model_config = _RECORD
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
    floor_estimated: bool | None = Field(
        None, description="true: the floor is estimated from a residual, no instrument stated"
    )
    failed: Count = Field(0, description="poses whose readings no pose closes")


class InputRecord(BaseModel):
    model_config = _RECORD
    role: str
    name: str
    sha256: str


class Provenance(BaseModel):
    model_config = _RECORD
    hexcal_version: str = __version__
    created: datetime = Field(default_factory=lambda: datetime.now(timezone.utc))
    poses: Count
    inputs: list[InputRecord] = Field(default_factory=list)


class CovarianceRecord(BaseModel):
    """The covariance of the model's parameters (format version 2): ``parameters`` names them
    in the fit's order (a1.x … b6.z, offset1 … offset6 for Model 42, then the effects'), and
    ``matrix`` (p × p) is in their units squared (mm², mm·ppm, ppm²…)."""

    model_config = _RECORD
    parameters: list[str]
    matrix: list[
        list[Annotated[float, Field(ge=-MAX_COVARIANCE, le=MAX_COVARIANCE, allow_inf_nan=False)]]
    ]


PoseKey = Annotated[str, Field(pattern=rf"^[0-9a-f]{{{KEY_HEX}}}$")]


class FingerprintRecord(BaseModel):
    """The fitted poses' values as keys (format version 3; :mod:`hexcal.io.pose_fingerprint`):
    each pose's key on a grid of ``quantum_mm`` (position, readings) and ``quantum_rad``
    (rotation vector), and on the grid shifted by half a step."""

    model_config = _RECORD
    quantum_mm: Annotated[float, NotBool] = Field(QUANTUM_MM, gt=0, le=1)
    quantum_rad: Annotated[float, NotBool] = Field(QUANTUM_RAD, gt=0, le=1e-3)
    keys: list[PoseKey]
    shifted: list[PoseKey]

    @classmethod
    def of(cls, meas) -> FingerprintRecord:
        fp = fingerprint(meas)
        return cls(keys=fp.keys, shifted=fp.shifted)


class FittedPoses(BaseModel):
    """The poses the model was fitted on (format version 2): their ids and times (s), and
    (version 3) the ``fingerprint`` of their values, by which ``hexcal validate`` knows them
    again in any copy (the ids and times are kept for the reader; they identify nothing)."""

    model_config = _RECORD
    pose_id: list[Annotated[int, Field(ge=1, le=2**53 - 1)]]
    t: list[Annotated[float, Field(ge=-1e9, le=1e9, allow_inf_nan=False)]]
    fingerprint: FingerprintRecord | None = None


class UncertaintyRecord(BaseModel):
    """The leg-length uncertainty terms beyond the parameters and the readings (format version
    3; :class:`hexcal.estimate.uncertainty.SessionTerms`, docs/metrology.md): the model
    inadequacy from the fit's held-out residual and its floor, and once a second session was
    validated (``hexcal validate --fold-in``) the between-session term from its residual."""

    model_config = _RECORD
    heldout_rms_mm: Statistic | None = Field(None, description="h: the fit's held-out leg RMS")
    floor_mm: Statistic | None = Field(None, description="f: the leg RMS the noise alone gives")
    parameters_mm: Statistic | None = Field(
        None, description="p: the leg RMS the parameters' covariance gives on the fitted poses"
    )
    model_inadequacy_mm: Statistic = Field(0.0, description="u_m = √max(0, h² − f² − 5/4·p²)")
    between_session_mm: Statistic | None = Field(
        None, description="u_b = √max(0, r² − h²), r a validated second session's leg RMS"
    )
    between_session_dof: Count | None = Field(
        None, description="its degrees of freedom (6: one session, a draw per leg)"
    )
    between_session_leg_rms_mm: Statistic | None = None
    between_session_poses: Count | None = None
    between_session_source: str | None = Field(None, max_length=400)


class CalibrationBlock(BaseModel):
    """The ``calibration`` key of calibrated.json."""

    model_config = _RECORD
    format: Literal["hexcal-calibrated-model"] = FORMAT
    format_version: Annotated[int, NotBool] = Field(1, ge=1, le=FORMAT_VERSION)
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
    covariance: CovarianceRecord | None = Field(
        None, description="the parameters' covariance (absent when the fit did not determine it)"
    )
    fitted_poses: FittedPoses | None = None
    uncertainty: UncertaintyRecord | None = None

    @property
    def _fingerprinted(self) -> bool:
        fp = self.fitted_poses is not None and self.fitted_poses.fingerprint is not None
        return fp or self.uncertainty is not None

    @model_validator(mode="after")
    def _version_holds_the_sources(self) -> CalibrationBlock:
        has = [
            what
            for what, held in (
                ("effect sources", any(e.source is not None for e in self.effects)),
                ("covariance", self.covariance is not None),
                ("fitted_poses", self.fitted_poses is not None),
                ("fingerprint or uncertainty", self._fingerprinted),
            )
            if held
        ]
        need = format_version_of(
            self.effects,
            covariance=self.covariance is not None,
            fitted_poses=self.fitted_poses is not None,
            fingerprint=self._fingerprinted,
        )
        if self.format_version < need:
            raise ValueError(
                f"format_version {self.format_version} has no {' nor '.join(has)}; a file "
                f"holding them is format_version {need}"
            )
        return self


class CalibratedRobot(Robot):
    """calibrated.json: a robot.json whose geometry is calibrated, plus ``calibration``."""

    model_config = ConfigDict(defer_build=True)  # see _RECORD

    calibration: CalibrationBlock

    def leg_model(self) -> LegModel:
        """The model as a predictor (geometry and effects)."""
        effects = tuple(e.name for e in self.calibration.effects)
        values = [p.value for e in self.calibration.effects for p in e.parameters]
        return LegModel(self.plain_robot(), effects, np.array(values, float))

    def source_notes(self, where: str) -> list[str]:
        """One line per effect whose loaded code comes from elsewhere than the code it was
        fitted with (another package version, another file): the parameters may not mean the
        same. Empty when every effect is what the file records."""
        notes = []
        for e in self.calibration.effects:
            recorded = None if e.source is None else e.source.effect_source()
            loaded = CATALOGUE.get(e.name)
            if loaded is None:  # not loaded at all: parse_model refuses such a model
                continue
            now = loaded.source
            if recorded is None and now.kind == "catalogue":
                continue
            if recorded is not None and _same_source(recorded, now):
                continue
            was = "hexcal's catalogue" if recorded is None else recorded.text()
            notes.append(
                f"{where}: the effect {e.name} was fitted with {was}; the one loaded now is from "
                f"{now.text()}: if its parameters mean something else, calibrate again"
            )
        return notes

    def parameter_covariance(self) -> ParameterCovariance | None:
        """The covariance of the model's parameters (None in a file without it)."""
        c = self.calibration.covariance
        if c is None:
            return None
        return ParameterCovariance(tuple(c.parameters), np.array(c.matrix, float))

    def fitted_pose_keys(self) -> set[tuple[int, float]] | None:
        """{(pose id, t rounded to 1 µs)} of the poses fitted (None when the file has no list)."""
        f = self.calibration.fitted_poses
        if f is None:
            return None
        return {(int(i), round(float(t), 6)) for i, t in zip(f.pose_id, f.t, strict=True)}

    def fitted_rows(self, meas) -> tuple[np.ndarray, str] | None:
        """((N,) bool, how): which rows of the table ``meas`` the model was fitted on, and by
        what they were known — their values (the fingerprint, version 3), or in an older file
        their ids and times. None when the file lists no fitted poses."""
        f = self.calibration.fitted_poses
        if f is None:
            return None
        fp = f.fingerprint
        if fp is not None:
            if (fp.quantum_mm, fp.quantum_rad) != (QUANTUM_MM, QUANTUM_RAD):
                return None  # another grid: its keys cannot be compared with this one's
            rows = shared_rows(meas, Fingerprint(fp.keys, fp.shifted))
            return rows, "the same positions, orientations and readings as the model's"
        keys = self.fitted_pose_keys() or set()
        pairs = zip(meas.pose_id.tolist(), np.round(meas.t, 6).tolist(), strict=True)
        rows = np.array([(int(i), float(t)) in keys for i, t in pairs], dtype=bool)
        return rows, "same pose ids and times as the model's; the file has no fingerprint"

    def session_terms(self) -> SessionTerms:
        """The uncertainty terms the file states (none in a file before version 3)."""
        u = self.calibration.uncertainty
        if u is None:
            return SessionTerms()
        dof = u.between_session_dof or SESSION_DOF
        return SessionTerms(u.model_inadequacy_mm, u.between_session_mm, dof)

    def with_between_session(self, leg_rms_mm: float, poses: int, source: str) -> CalibratedRobot:
        """This model with the between-session term of a second session whose leg-length RMS
        (the model held fixed) was ``leg_rms_mm`` over ``poses`` poses, from ``source`` (its
        file): u_b = √max(0, r² − h²), h the fit's held-out RMS. Raises ValueError when the
        file records no h."""
        block = self.calibration
        u = block.uncertainty
        h = u.heldout_rms_mm if u is not None else block.fit.heldout_rms_mm
        if h is None:
            raise ValueError(
                "the model records no held-out residual to compare a second session with: "
                "calibrate it again with this hexcal"
            )
        record = UncertaintyRecord.model_validate(
            (u.model_dump() if u is not None else {"heldout_rms_mm": h})
            | {
                "between_session_mm": excess_mm(leg_rms_mm, h),
                "between_session_dof": SESSION_DOF,
                "between_session_leg_rms_mm": leg_rms_mm,
                "between_session_poses": poses,
                "between_session_source": source,
            }
        )
        version = max(block.format_version, FINGERPRINT_VERSION)
        new = block.model_copy(update={"uncertainty": record, "format_version": version})
        return self.model_copy(update={"calibration": new})

    def plain_robot(self) -> Robot:
        """The geometry as a plain robot.json (the calibration block left out)."""
        return Robot.model_validate(self.model_dump(exclude={"calibration"}, exclude_none=True))

    def to_json(self) -> str:
        """calibrated.json text (indent 2); NaN or infinity anywhere is refused, not written."""
        return json_text(self.model_dump(mode="json", exclude_none=True))


def _same_source(a: EffectSource, b: EffectSource) -> bool:
    if a.kind != b.kind:
        return False
    if a.kind == "package":
        return (a.package, a.version) == (b.package, b.version)
    if a.kind == "file":
        return a.sha256 == b.sha256
    return a.module == b.module


def format_version_of(
    effects: list[EffectRecord],
    *,
    covariance: bool = False,
    fitted_poses: bool = False,
    fingerprint: bool = False,
) -> int:
    """The format version a file needs: 3 when it holds the fitted poses' ``fingerprint`` (or
    uncertainty terms); 2 when an effect records its source, or the file holds the parameters'
    ``covariance`` or its ``fitted_poses``; 1 otherwise."""
    if fingerprint:
        return FINGERPRINT_VERSION
    sources = any(e.source is not None for e in effects)
    return SOURCE_VERSION if (sources or covariance or fitted_poses) else 1


def effect_records(model: LegModel, sigmas: dict[str, float] | None = None) -> list[EffectRecord]:
    """The model's effects with their values, in spec units; ``sigmas`` by parameter name;
    where each comes from when it is not hexcal's catalogue."""
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
        out.append(
            EffectRecord(
                name=e, parameters=params, physics=eff.physics, source=SourceRecord.of(eff.source)
            )
        )
    return out


def covariance_record(
    names: list[str], cov: np.ndarray, sigma: np.ndarray, model: LegModel, fit_offsets: bool
) -> CovarianceRecord | None:
    """The covariance of ``model``'s parameters out of a fit's (``names`` (q,), ``cov`` (q, q),
    ``sigma`` (q,)): its rows and columns in the model's order, the session's own effects left
    out. None when a parameter of the model is missing from the fit or undetermined (infinite
    σ): a covariance that claims to know it would understate the uncertainty."""
    wanted = model_parameter_names(model, fit_offsets)
    if any(n not in names for n in wanted):
        return None
    idx = [names.index(n) for n in wanted]
    if not np.all(np.isfinite(np.asarray(sigma)[idx])):
        return None
    m = np.asarray(cov, float)[np.ix_(idx, idx)]
    if not np.all(np.isfinite(m)):
        return None
    return CovarianceRecord(parameters=wanted, matrix=(0.5 * (m + m.T)).tolist())


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
        _check_effects_loaded(robot, where)
        try:
            model = robot.leg_model()
        except ValidationError as exc:
            raise RobotFileError(format_validation_error(exc, where)) from None
        except ValueError as exc:
            raise RobotFileError(f"{where}: field calibration.effects: {exc}") from None
        _check_parameter_names(robot, where)
        _check_covariance(robot.calibration, model, where)
        _check_fitted_poses(robot.calibration, where)
    return robot


def _check_covariance(block: CalibrationBlock, model: LegModel, where: str) -> None:
    """The covariance names the model's parameters in order, is square, symmetric and has no
    negative variance; otherwise the file is refused with the field named."""
    c = block.covariance
    if c is None:
        return
    field = f"{where}: field calibration.covariance"
    expected = model_parameter_names(model, block.kind == 42)
    if c.parameters != expected:
        raise RobotFileError(
            f"{field}.parameters: expected the model's {len(expected)} parameters in order "
            f"({expected[0]} … {expected[-1]}), got {len(c.parameters)}; the covariance does not "
            "belong to this model: calibrate again, or remove the key"
        )
    p = len(expected)
    if len(c.matrix) != p or any(len(row) != p for row in c.matrix):
        raise RobotFileError(f"{field}.matrix: must be {p} rows of {p} numbers")
    m = np.array(c.matrix, float)
    scale = max(float(np.max(np.abs(m))), 1e-300)
    if np.max(np.abs(m - m.T)) > 1e-9 * scale:
        raise RobotFileError(f"{field}.matrix: not symmetric; a covariance matrix is")
    if (np.diag(m) < 0).any():
        k = int(np.argmin(np.diag(m)))
        raise RobotFileError(
            f"{field}.matrix: the variance of {expected[k]} is negative ({m[k, k]:g})"
        )


def _check_fitted_poses(block: CalibrationBlock, where: str) -> None:
    f = block.fitted_poses
    if f is not None and len(f.pose_id) != len(f.t):
        raise RobotFileError(
            f"{where}: field calibration.fitted_poses: {len(f.pose_id)} pose ids but "
            f"{len(f.t)} times; each fitted pose has one of each"
        )


def _check_effects_loaded(robot: CalibratedRobot, where: str) -> None:
    """Refuse a model one of whose effects this process has not loaded, naming where the effect
    came from and what to install or pass."""
    for i, e in enumerate(robot.calibration.effects):
        field = f"field calibration.effects.{i} ({e.name})"
        if e.name not in CATALOGUE:
            failed = failure_of(e.name)
            if failed:
                raise RobotFileError(f"{where}: {field}: {failed}: fix or reinstall the package")
            if e.source is None:
                raise RobotFileError(
                    f"{where}: {field}: the effect is not in this hexcal's catalogue "
                    f"({', '.join(sorted(CATALOGUE))}); the file records no source for it: "
                    "install or pass (--effects FILE.py) the code that defines it"
                )
            src = e.source.effect_source()
            raise RobotFileError(
                f"{where}: {field}: the effect comes from {src.text()}, which is not loaded: "
                f"{src.how_to_get()}, then run again"
            )


def _check_parameter_names(robot: CalibratedRobot, where: str) -> None:
    """Refuse a model whose effect's parameters are not those the effect loaded now has."""
    plain = robot.plain_robot()
    for i, e in enumerate(robot.calibration.effects):
        field = f"field calibration.effects.{i} ({e.name})"
        names = [s.name for s in get_effect(e.name).params(plain)]
        recorded = [p.name for p in e.parameters]
        if recorded != names:
            raise RobotFileError(
                f"{where}: {field}: the file holds the parameters {', '.join(recorded)}; the "
                f"effect loaded now (from {get_effect(e.name).source.text()}) has "
                f"{', '.join(names)}: load the version of the effect the model was fitted with, "
                "or calibrate again"
            )


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
