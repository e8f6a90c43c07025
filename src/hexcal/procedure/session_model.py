"""The session file's content as types (pydantic v2): poses with their raw samples, poses set
aside, notes, progress, results, and the :class:`Session` that holds them (docs/formats.md, "The
session file"). Reading and writing the file, and the one-writer rule, are in
:mod:`hexcal.procedure.session`, which offers these names too.

Numbers: every number is finite and within the limits of :mod:`hexcal.io.safe_read` (positions
and readings ±1 km, times ±1e9 s, pose ids 1 .. 2**53 − 1, no boolean for a number). A pose
holding NaN or infinity is refused on construction (:class:`SessionFileError`), never saved.

Times: ``t`` of a pose is seconds since the session started (the interchange table's ``t``);
raw sample times are the host's monotonic clock (s) of the recording run they came from, so
only differences within one run are meaningful; ``recorded_at`` is wall-clock UTC.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Final, Literal

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    ValidationError,
    field_validator,
)

from hexcal import __version__
from hexcal.acquire.acquisition import LegSample, RecordedPose, TrackerSample
from hexcal.acquire.devices import DevicesConfig
from hexcal.errors import InputError
from hexcal.estimate.model_file import CalibratedRobot
from hexcal.io.json_out import accuracy_reason, strict
from hexcal.io.measurements import REQUIRED_COLUMNS, Measurements
from hexcal.io.safe_read import (
    MAX_COORDINATE_MM,
    Celsius,
    Count,
    Finite,
    Millimetres,
    PoseId,
    QuaternionPart,
    Seconds,
)
from hexcal.io.validation import format_validation_error
from hexcal.model.instruments import Instruments
from hexcal.model.robot import Robot
from hexcal.vocabulary import Constraint, ConstraintField, ModelKindField

#: 3: an imported table's poses may sit in a pose block beside the file (``pose_block``).
SCHEMA_VERSION: Final = 3
#: The columns of the interchange table that are not extra columns.
_TABLE_COLUMNS = frozenset((*REQUIRED_COLUMNS, "temperature"))


def _now() -> datetime:
    return datetime.now(timezone.utc)


def _usable(v: float) -> bool:
    return math.isfinite(v) and abs(v) <= MAX_COORDINATE_MM


def _nan_to_none(values: Iterable[float]) -> list[float | None]:
    """Values as saved in a raw sample: None where the device gave no number (NaN, infinity,
    or beyond the ±1 km of :data:`~hexcal.io.safe_read.MAX_COORDINATE_MM`)."""
    return [float(v) if _usable(float(v)) else None for v in values]


def _none_to_nan(values: Sequence[float | None]) -> np.ndarray:
    return np.array([math.nan if v is None else v for v in values], float)


class SessionFileError(InputError):
    """A session file cannot be read or written; the message names it and says what to do."""


class RawTrackerSample(BaseModel):
    """One tracker sample: ``t`` host monotonic s; position (3,) mm and quaternion (4,) scalar
    first, None when the device gave no pose; ``rms_mm``; ``fault`` sentence or None."""

    model_config = ConfigDict(extra="forbid")
    t: Seconds
    position: list[Millimetres] | None = Field(None, min_length=3, max_length=3)
    quaternion: list[QuaternionPart] | None = Field(None, min_length=4, max_length=4)
    rms_mm: Finite | None = Field(None, ge=0, le=MAX_COORDINATE_MM)
    fault: str | None = None

    @classmethod
    def of(cls, s: TrackerSample) -> RawTrackerSample:
        """The sample as saved. A position or quaternion holding a non-number (a device fault
        the driver did not flag) is saved as None, and the sample flagged with a fault, so
        the file never holds NaN and the sample is never taken for a good one."""
        rms = float(s.rms_mm) if _usable(float(s.rms_mm)) and s.rms_mm >= 0 else None
        position, quaternion, fault = s.position, s.quaternion, s.fault
        bad: list[str] = []
        if position is not None and not all(_usable(float(v)) for v in position):
            position, bad = None, [*bad, "position"]
        if quaternion is not None and not all(
            math.isfinite(float(v)) and abs(float(v)) <= 2 for v in quaternion
        ):
            quaternion, bad = None, [*bad, "quaternion"]
        if bad and not fault:
            fault = f"the tracker's {' and '.join(bad)} was not a number"
        return cls(
            t=s.t,
            position=None if position is None else [float(v) for v in position],
            quaternion=None if quaternion is None else [float(v) for v in quaternion],
            rms_mm=rms,
            fault=fault,
        )


class RawLegSample(BaseModel):
    """One set of six readings: ``t`` host monotonic s (its SYNC); readings (6,) mm, None where
    a leg gave none; the faults the bus reported for it."""

    model_config = ConfigDict(extra="forbid")
    t: Seconds
    readings: list[Millimetres | None] = Field(min_length=6, max_length=6)
    faults: list[str] = Field(default_factory=list)

    @classmethod
    def of(cls, s: LegSample) -> RawLegSample:
        """The set as saved: a reading that is not a number in range is saved as None, and,
        when the bus reported no fault for the set, the set is flagged with one."""
        readings = _nan_to_none(s.readings)
        faults = list(s.faults)
        missing = [str(k + 1) for k, r in enumerate(readings) if r is None]
        if missing and not faults:
            faults.append(f"leg {', '.join(missing)}: the reading was not a number")
        return cls(t=s.t, readings=readings, faults=faults)


class PoseRecord(BaseModel):
    """One recorded pose: the row of the interchange table plus its raw samples.

    ``quaternion`` is kept exactly as recorded or imported (not renormalised); ``extra`` holds
    an imported table's extra columns as text, so export gives the table back unchanged.

    Units: ``t`` s since the session started; position mm; readings mm; temperature degC.
    Every number is finite and in range (:mod:`hexcal.io.safe_read`): a NaN or infinity is
    refused on construction."""

    model_config = ConfigDict(extra="forbid")
    pose_id: PoseId
    t: Seconds
    step: str
    leg: int = Field(ge=0, le=6)
    constraint: ConstraintField
    position: list[Millimetres] = Field(min_length=3, max_length=3)
    quaternion: list[QuaternionPart] = Field(min_length=4, max_length=4)
    readings: list[Millimetres] = Field(min_length=6, max_length=6)
    temperature: Celsius | None = None
    recorded_at: datetime | None = None
    notes: list[str] = Field(default_factory=list)
    extra: dict[str, str] = Field(default_factory=dict)
    tracker_samples: list[RawTrackerSample] = Field(default_factory=list)
    leg_samples: list[RawLegSample] = Field(default_factory=list)


class SetAside(BaseModel):
    """A pose refused at recording (``pose`` None) or recorded and then set aside because its
    step failed a check; ``reason`` is the message the operator saw. ``unreadable_pose`` keeps,
    exactly as it was in the file, a pose an older hexcal saved with ``null`` values (no valid
    :class:`PoseRecord` can hold it): set aside on load, nothing of it lost."""

    model_config = ConfigDict(extra="forbid")
    step: str
    reason: str
    at: datetime = Field(default_factory=_now)
    pose: PoseRecord | None = None
    unreadable_pose: dict[str, Any] | None = None


class OperatorNote(BaseModel):
    model_config = ConfigDict(extra="forbid")
    at: datetime = Field(default_factory=_now)
    text: str


class StepProgress(BaseModel):
    """A procedure step the guided session has finished (``done``: its poses passed their
    checks) or that the operator skipped; a resumed session starts at the first step with none."""

    model_config = ConfigDict(extra="forbid")
    step: str
    status: Literal["done", "skipped"]
    poses: Count = 0
    at: datetime = Field(default_factory=_now)
    check: str = Field("", description="the end-of-step check, in words")


class ResultRecord(BaseModel):
    """A calibration or diagnosis computed in the session: the model, the effects fitted with
    it, the calibrated robot (robot.json content) and a JSON summary (RMS, χ², verdict...)."""

    model_config = ConfigDict(extra="forbid")
    kind: Literal["calibration", "diagnosis"]
    at: datetime = Field(default_factory=_now)
    model: ModelKindField
    effects: list[str] = Field(default_factory=list)
    pose_ids: list[PoseId] = Field(default_factory=list, description="the poses it used")
    robot: Robot | None = None
    calibrated: CalibratedRobot | None = Field(
        None, description="the whole model: geometry and effects (calibrated.json's content)"
    )
    summary: dict[str, Any] = Field(default_factory=dict)

    @field_validator("summary")
    @classmethod
    def _strict(cls, summary: dict[str, Any]) -> dict[str, Any]:
        # Free-form: a figure that could not be computed is null with its reason beside it.
        return strict(summary, accuracy_reason)


class EncoderReboot(BaseModel):
    """A leg's encoder rebooted (its node's boot-up while recording) before the pose
    ``pose_id``: that pose and every later one were read after it, when an encoder that kept
    no preset reads off by its lost zero. ``jump_mm``: at that pose, how far the leg's reading
    moved against its prediction from the tracker's pose and the model, beyond the scatter of
    that difference over the poses before (None: too few poses before to judge); ``beyond``:
    whether the jump exceeds what that scatter and the noise allow (marked at once)."""

    model_config = ConfigDict(extra="forbid")
    leg: int = Field(ge=1, le=6)
    pose_id: PoseId
    jump_mm: Millimetres | None = None
    threshold_mm: Millimetres | None = None
    beyond: bool = False


class PoseBlock(BaseModel):
    """Where a session keeps an imported table's poses: the pose block ``file`` beside the
    session file (:mod:`hexcal.io.pose_block`), its ``poses`` (at most
    :data:`hexcal.io.capacity.MAX_IMPORTED_POSES`, checked on load), the SHA-256 of its
    records, and each text column's distinct values in code order (``step``, ``constraint``,
    then the session's extra columns in ``columns`` order)."""

    model_config = ConfigDict(extra="forbid")
    file: str = Field(pattern=r"^[^/\\]+\.poses\.npy$", description="a name beside the session")
    poses: int = Field(ge=1)
    sha256: str = Field(pattern="^[0-9a-f]{64}$")
    texts: dict[str, list[str]]


class Session(BaseModel):
    """A calibration session (see the module docstring).

    The poses are ``poses`` (recorded, with their raw samples) after, when the session was
    imported from a table, that table's rows, kept in a pose block beside the file
    (``pose_block``; :mod:`hexcal.procedure.session_block` reads and writes it)."""

    model_config = ConfigDict(extra="forbid")
    schema_version: Literal[1, 2, 3] = SCHEMA_VERSION
    hexcal_version: str = __version__
    created: datetime = Field(default_factory=_now)
    robot: Robot
    devices: DevicesConfig | None = None
    instruments: Instruments | None = Field(
        None, description="the noise of the recorded poses (stated, or estimated from them)"
    )
    procedure: dict[str, Any] | None = Field(
        None, description="the procedure as loaded from its TOML file"
    )
    columns: list[str] = Field(
        default_factory=lambda: list(REQUIRED_COLUMNS),
        description="the interchange table's header, in the order export writes it",
    )
    poses: list[PoseRecord] = Field(default_factory=list)
    set_aside: list[SetAside] = Field(default_factory=list)
    notes: list[OperatorNote] = Field(default_factory=list)
    results: list[ResultRecord] = Field(default_factory=list)
    progress: list[StepProgress] = Field(
        default_factory=list, description="the guided procedure's finished and skipped steps"
    )
    encoder_reboots: list[EncoderReboot] = Field(
        default_factory=list,
        description="the legs whose encoder rebooted while recording, and the first pose after",
    )
    pose_block: PoseBlock | None = Field(
        None, description="an imported table's poses, in a binary file beside this one"
    )
    #: The imported table (the pose block's rows), once read or before it is first written.
    _table: Measurements | None = PrivateAttr(None)
    #: The pose block file ``_table`` was read from or written to (None: not yet written).
    _block_path: Path | None = PrivateAttr(None)
    #: Reads ``_table`` from the pose block (set with ``_block_path``).
    _table_source: Callable[[], Measurements] | None = PrivateAttr(None)

    # -- the imported table ---------------------------------------------------------------------
    def pose_count(self) -> int:
        """Every pose the session holds: the imported table's (its pose block's count, as the
        session file gives it: the block is not read) and the recorded ones. What the text UI
        shows; the sessions list counts the same from the file's JSON
        (:func:`hexcal.procedure.sessions_dir.list_sessions`)."""
        if self._table is not None:  # read, or not written yet
            table = len(self._table)
        else:
            table = self.pose_block.poses if self.pose_block is not None else 0
        return table + len(self.poses)

    def imported(self) -> Measurements | None:
        """The imported table's rows (read from the pose block the first time), or None."""
        if self._table is None and self.pose_block is not None:
            if self._table_source is None:
                raise SessionFileError("the session's pose block has no file to be read from")
            self._table = self._table_source()
        return self._table

    # -- the interchange table ----------------------------------------------------------------
    def measurements(self) -> Measurements:
        """The session's poses as the measurement table (every pose, in order: the imported
        table's, then the recorded ones)."""
        table = self.imported()
        if not self.poses:
            if table is None:
                raise SessionFileError("the session has no recorded pose yet")
            return table
        recorded = self._recorded()
        if table is None:
            return recorded
        return _joined(table, recorded)

    def _recorded(self) -> Measurements:
        p = self.poses
        temps = [r.temperature for r in p]
        # The interchange table has no empty temperature cell: the column goes out with every
        # pose's temperature known, or not at all (poses recorded before one was entered).
        has_t = "temperature" in self.columns and None not in temps
        columns = [c for c in self.columns if has_t or c != "temperature"]
        extra_names = [c for c in self.columns if c not in _TABLE_COLUMNS]
        return Measurements(
            pose_id=np.asarray([r.pose_id for r in p]),
            t=np.asarray([r.t for r in p], float),
            step=np.asarray([r.step for r in p], object),
            leg=np.asarray([r.leg for r in p]),
            constraint=np.asarray([r.constraint.value for r in p], object),
            position=np.asarray([r.position for r in p], float),
            quaternion=np.asarray([r.quaternion for r in p], float),
            readings=np.asarray([r.readings for r in p], float),
            temperature=_none_to_nan(temps) if has_t else None,
            extra={k: np.asarray([r.extra.get(k, "") for r in p], object) for k in extra_names},
            columns=tuple(columns),
        )

    @classmethod
    def from_measurements(
        cls, meas: Measurements, robot: Robot, devices: DevicesConfig | None = None
    ) -> Session:
        """A session holding an imported table (no raw samples): export gives it back."""
        poses = [
            PoseRecord(
                pose_id=int(meas.pose_id[i]),
                t=float(meas.t[i]),
                step=str(meas.step[i]),
                leg=int(meas.leg[i]),
                constraint=str(meas.constraint[i]),
                position=[float(v) for v in meas.position[i]],
                quaternion=[float(v) for v in meas.quaternion[i]],
                readings=[float(v) for v in meas.readings[i]],
                temperature=None if meas.temperature is None else _finite(meas.temperature[i]),
                extra={k: str(v[i]) for k, v in meas.extra.items()},
            )
            for i in range(len(meas))
        ]
        return cls(robot=robot, devices=devices, columns=list(meas.columns), poses=poses)

    @classmethod
    def with_table(
        cls, meas: Measurements, robot: Robot, devices: DevicesConfig | None = None
    ) -> Session:
        """A session holding an imported table as its pose block (written beside the session
        file when it is first saved): export gives it back."""
        session = cls(robot=robot, devices=devices, columns=list(meas.columns))
        session._table = meas
        return session

    # -- recording ------------------------------------------------------------------------------
    def next_pose_id(self) -> int:
        table = self.imported()
        used = [r.pose_id for r in self.poses] + [
            s.pose.pose_id for s in self.set_aside if s.pose is not None
        ]
        unreadable = [_unreadable_id(s.unreadable_pose) for s in self.set_aside]
        used += [u for u in unreadable if u is not None]
        if table is not None and len(table):
            used.append(int(table.pose_id.max()))
        return max(used, default=0) + 1

    def pose_record(
        self,
        pose: RecordedPose,
        step: str,
        leg: int,
        constraint: Constraint,
        t: float,
        temperature: float | None = None,
    ) -> PoseRecord:
        """A :class:`PoseRecord` of a recorded pose, numbered after every pose so far.

        Raises :class:`SessionFileError` when the pose holds a NaN, an infinity or a value out
        of range: the last line of defence, so that no such pose is ever saved (the drivers
        flag the samples that would give one)."""
        try:
            return PoseRecord(
                pose_id=self.next_pose_id(),
                t=t,
                step=step,
                leg=leg,
                constraint=constraint,
                position=[float(v) for v in pose.position],
                quaternion=[float(v) for v in pose.quaternion],
                readings=[float(v) for v in pose.readings],
                temperature=pose.temperature if temperature is None else temperature,
                recorded_at=_now(),
                notes=list(pose.notes),
                tracker_samples=[RawTrackerSample.of(s) for s in pose.tracker_samples],
                leg_samples=[RawLegSample.of(s) for s in pose.leg_samples],
            )
        except ValidationError as exc:
            raise SessionFileError(
                format_validation_error(exc, f"pose of step {step!r} not saved")
                + "\na pose must hold finite numbers in range: check the devices (a fault "
                "their drivers did not flag), then record the pose again"
            ) from None


def _joined(table: Measurements, recorded: Measurements) -> Measurements:
    """The imported ``table``'s rows then the ``recorded`` poses' as one table (the header of
    both; a temperature column only when both have one)."""
    both_t = table.temperature is not None and recorded.temperature is not None
    columns = tuple(c for c in table.columns if both_t or c != "temperature")
    return Measurements(
        pose_id=np.concatenate([table.pose_id, recorded.pose_id]),
        t=np.concatenate([table.t, recorded.t]),
        step=np.concatenate([table.step, recorded.step]),
        leg=np.concatenate([table.leg, recorded.leg]),
        constraint=np.concatenate([table.constraint, recorded.constraint]),
        position=np.concatenate([table.position, recorded.position]),
        quaternion=np.concatenate([table.quaternion, recorded.quaternion]),
        readings=np.concatenate([table.readings, recorded.readings]),
        temperature=(np.concatenate([table.temperature, recorded.temperature]) if both_t else None),
        extra={k: np.concatenate([v, recorded.extra[k]]) for k, v in table.extra.items()},
        columns=columns,
    )


def _finite(v: float) -> float | None:
    return float(v) if math.isfinite(float(v)) else None


def _unreadable_id(pose: dict[str, Any] | None) -> int | None:
    pid = None if pose is None else pose.get("pose_id")
    return pid if isinstance(pid, int) and not isinstance(pid, bool) and pid >= 1 else None
