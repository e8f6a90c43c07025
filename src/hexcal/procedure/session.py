"""The session file: everything a calibration session recorded and computed, in one JSON file.

A :class:`Session` (pydantic v2) holds the robot description, the device configuration, the
procedure, every recorded pose with its raw samples and timestamps, the poses that were refused
or set aside (with the reason), operator notes, and each calibration and diagnosis result with
the model it used. ``schema_version`` says which layout the file follows (``hexcal schema``
prints the JSON Schema).

Safety: :class:`SessionFile` saves the whole session atomically (temporary file, fsync, rename,
fsync of the directory) after every change, so a kill at any instant leaves either the previous
file or the new one. A file that is not valid JSON, not a session, or written by a newer hexcal
(higher ``schema_version``) is refused with a message naming it, and is never overwritten:
:class:`SessionFile` only writes to a path it created or loaded cleanly itself.

Numbers: every number in a session is finite and within the limits of :mod:`hexcal.io.safe_read`
(positions and readings ±1 km, times ±1e9 s, pose ids 1 .. 2**53 − 1). A pose holding NaN or
infinity is refused on construction (:class:`SessionFileError`), never saved. A file from an
older hexcal, which saved such values as ``null``, still loads: each pose with a ``null`` where a
number belongs is moved to ``set_aside`` whole (``unreadable_pose``), with a reason naming the pose
and the field; nothing else changes.

Times: ``t`` of a pose is seconds since the session started (the interchange table's ``t``);
raw sample times are the host's monotonic clock (s) of the recording run they came from, so
only differences within one run are meaningful; ``recorded_at`` is wall-clock UTC.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Iterable, Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Final, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from hexcal import __version__
from hexcal.acquire.acquisition import LegSample, RecordedPose, TrackerSample
from hexcal.acquire.devices import DevicesConfig
from hexcal.effects.priors import check_priors
from hexcal.errors import InputError
from hexcal.estimate.model_file import CalibratedRobot, save_model
from hexcal.io.fileio import remove_orphan_temp_files, write_text_atomic
from hexcal.io.measurements import REQUIRED_COLUMNS, Measurements
from hexcal.io.safe_read import (
    MAX_COORDINATE_MM,
    Celsius,
    Count,
    Millimetres,
    PoseId,
    QuaternionPart,
    Seconds,
    read_json,
)
from hexcal.io.validation import format_validation_error, shown_value
from hexcal.model.instruments import Instruments
from hexcal.model.robot import Robot
from hexcal.procedure import looks_like_session as looks_like_session
from hexcal.vocabulary import Constraint, ConstraintField, ModelKindField

log = logging.getLogger(__name__)
# The notices are returned to the interface; logging is for an application that configures it
# (without a handler, Python would print the warnings over the text UI's screen).
log.addHandler(logging.NullHandler())

SCHEMA_VERSION: Final = 2


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
    rms_mm: float | None = Field(None, ge=0, le=MAX_COORDINATE_MM, allow_inf_nan=False)
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


class Session(BaseModel):
    """A calibration session (see the module docstring)."""

    model_config = ConfigDict(extra="forbid")
    schema_version: Literal[1, 2] = SCHEMA_VERSION
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

    # -- the interchange table ----------------------------------------------------------------
    def measurements(self) -> Measurements:
        """The recorded poses as the measurement table (every pose, in order)."""
        if not self.poses:
            raise SessionFileError("the session has no recorded pose yet")
        p = self.poses
        temps = [r.temperature for r in p]
        # The interchange table has no empty temperature cell: the column goes out with every
        # pose's temperature known, or not at all (poses recorded before one was entered).
        has_t = "temperature" in self.columns and None not in temps
        columns = [c for c in self.columns if has_t or c != "temperature"]
        extra_names = [c for c in self.columns if c in p[0].extra]
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

    # -- recording ------------------------------------------------------------------------------
    def next_pose_id(self) -> int:
        used = [r.pose_id for r in self.poses] + [
            s.pose.pose_id for s in self.set_aside if s.pose is not None
        ]
        unreadable = [_unreadable_id(s.unreadable_pose) for s in self.set_aside]
        used += [u for u in unreadable if u is not None]
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


def _finite(v: float) -> float | None:
    return float(v) if math.isfinite(float(v)) else None


def _unreadable_id(pose: dict[str, Any] | None) -> int | None:
    pid = None if pose is None else pose.get("pose_id")
    return pid if isinstance(pid, int) and not isinstance(pid, bool) and pid >= 1 else None


#: The numbers of a pose an older hexcal may have saved as null (NaN, infinity): the table row's
#: and each raw sample's time. (A raw sample's own position, quaternion and readings may be null.)
_POSE_NUMBERS = ("t", "position", "quaternion", "readings")


def _null_fields(pose: dict[str, Any]) -> list[str]:
    """The fields of a saved pose that hold null where a number belongs."""
    found = []
    for key in _POSE_NUMBERS:
        if key not in pose:
            continue
        v = pose[key]
        if v is None:
            found.append(key)
        elif isinstance(v, list):
            found += [f"{key}.{j}" for j, x in enumerate(v) if x is None]
    for group in ("tracker_samples", "leg_samples"):
        samples = pose.get(group)
        if isinstance(samples, list):
            found += [
                f"{group}.{j}.t"
                for j, smp in enumerate(samples)
                if isinstance(smp, dict) and "t" in smp and smp["t"] is None
            ]
    return found


def _null_reason(pose: dict[str, Any], fields: list[str]) -> str:
    pid = pose.get("pose_id")
    name = f"pose {pid}" if isinstance(pid, int) else "a pose"
    listed = ", ".join(fields[:3]) + (f" and {len(fields) - 3} more" if len(fields) > 3 else "")
    verb = "was not a number" if len(fields) == 1 else "were not numbers"
    return f"{name}: {listed} {verb} (saved by an older hexcal); set aside on load"


def set_aside_null_poses(data: dict[str, Any]) -> list[str]:
    """Move every pose of a parsed session file that holds null where a number belongs (as an
    older hexcal saved NaN) to ``set_aside``, kept whole as ``unreadable_pose``; the same for a
    set-aside pose. The reasons, one per pose moved; everything else is left as it was."""
    reasons: list[str] = []
    poses, aside = data.get("poses"), data.get("set_aside", [])
    if not isinstance(aside, list):
        return reasons  # validation names the field
    if isinstance(poses, list):
        kept = []
        for p in poses:
            fields = _null_fields(p) if isinstance(p, dict) else []
            if not fields:
                kept.append(p)
                continue
            reason = _null_reason(p, fields)
            step = p.get("step") if isinstance(p.get("step"), str) else "?"
            aside.append({"step": step, "reason": reason, "unreadable_pose": p})
            reasons.append(reason)
        data["poses"] = kept
    for item in aside:
        pose = item.get("pose") if isinstance(item, dict) else None
        if not isinstance(pose, dict):
            continue
        fields = _null_fields(pose)
        if fields:
            reason = _null_reason(pose, fields)
            item["unreadable_pose"] = item.pop("pose")
            if isinstance(item.get("reason"), str):
                item["reason"] += f" — {reason}"
            reasons.append(reason)
    data["set_aside"] = aside
    return reasons


def session_json_schema() -> str:
    """The JSON Schema of the session file (``hexcal schema``)."""
    return json.dumps(Session.model_json_schema(), indent=2) + "\n"


def _error(message: str) -> SessionFileError:
    return SessionFileError(message)


def load_session(path: str | Path, notices: list[str] | None = None) -> Session:
    """Read a session file. Refuses — naming the file and saying what to do — a missing file,
    one that is not JSON or not a session, one beyond the limits of :mod:`hexcal.io.safe_read`
    (512 MB, nesting, non-finite numbers), and one written by a newer hexcal.

    Poses an older hexcal saved with ``null`` values are set aside (see the module docstring);
    each one's reason is appended to ``notices`` when given, and logged."""
    path = Path(path)
    data = read_json(path, "session", _error)
    if not isinstance(data, dict) or "schema_version" not in data:
        raise SessionFileError(
            f"{path}: not a hexcal session file (no schema_version); it is left untouched"
        )
    version = data["schema_version"]
    if isinstance(version, int) and not isinstance(version, bool) and version > SCHEMA_VERSION:
        raise SessionFileError(
            f"{path}: written by a newer hexcal (session schema {shown_value(version)}; this "
            f"hexcal {__version__} reads schema {SCHEMA_VERSION}) — upgrade hexcal to open it; "
            "the file is left untouched"
        )
    moved = set_aside_null_poses(data)
    try:
        session = Session.model_validate(data)
    except ValidationError as exc:
        raise SessionFileError(
            format_validation_error(exc, str(path), data)
            + "\nthe file is left untouched; fix the field or start a new session"
        ) from None
    robots = [session.robot] + [r for res in session.results for r in (res.robot, res.calibrated)]
    for robot in robots:
        if robot is not None:
            try:
                check_priors(robot, str(path))
            except ValueError as exc:
                raise SessionFileError(
                    f"{exc}\nthe file is left untouched; fix the field or start a new session"
                ) from None
    for reason in moved:
        log.warning("%s: %s", path, reason)
    if notices is not None:
        notices += [f"{path}: {reason}" for reason in moved]
    return session


def session_to_text(session: Session) -> str:
    """The session file's text (indented JSON)."""
    return session.model_dump_json(indent=1, exclude_none=False) + "\n"


class SessionFile:
    """A session bound to its file; every change is saved atomically at once.

    Use :meth:`create` for a new file (refused if the path exists: an existing session is
    resumed, never replaced) and :meth:`resume` for an existing one (refused if damaged)."""

    def __init__(self, path: Path, session: Session, notices: Sequence[str] = ()):
        self.path = path
        self.session = session
        #: What opening the file did, in words (orphan temporary files removed, poses set
        #: aside on load), for the interface to show; also logged.
        self.notices: list[str] = list(notices)

    @classmethod
    def create(cls, path: str | Path, session: Session) -> SessionFile:
        path = Path(path)
        if path.exists():
            raise SessionFileError(
                f"{path}: already exists — resume it, or choose another name; it is not overwritten"
            )
        sf = cls(path, session)
        sf.save()
        return sf

    @classmethod
    def resume(cls, path: str | Path) -> SessionFile:
        """Open an existing session to go on with it. Once it has loaded, the temporary files
        an interrupted save left next to it (named as :func:`hexcal.io.fileio.write_text_atomic`
        names them, for this file only) are removed and said so in :attr:`notices`; a file
        that does not load is refused with everything next to it left as it is."""
        path = Path(path)
        notices: list[str] = []
        session = load_session(path, notices)
        for tmp, size in remove_orphan_temp_files(path):
            text = (
                f"{tmp}: removed, a temporary file ({size} bytes) an interrupted save left; "
                f"{path.name} holds the last complete save"
            )
            log.warning("%s", text)
            notices.append(text)
        return cls(path, session, notices)

    def save(self) -> None:
        # A schema 1 file is upgraded when hexcal writes it (schema 2 only adds fields).
        self.session.schema_version = SCHEMA_VERSION
        try:
            write_text_atomic(self.path, session_to_text(self.session))
        except OSError as exc:
            raise SessionFileError(
                f"{self.path}: could not save the session ({exc.strerror or exc}); the last "
                "saved state is still on disk — free space or fix permissions, then record again"
            ) from None

    def add_pose(self, record: PoseRecord) -> None:
        if record.temperature is not None and "temperature" not in self.session.columns:
            # The table's temperature column comes with the first pose that has one (the
            # poses before it export an empty cell); it sits after the required columns.
            cols = self.session.columns
            at = max(cols.index(c) for c in REQUIRED_COLUMNS) + 1
            self.session.columns = [*cols[:at], "temperature", *cols[at:]]
        self.session.poses.append(record)
        self.save()

    def set_aside(self, item: SetAside) -> None:
        self.session.set_aside.append(item)
        self.save()

    def undo_last_pose(self, reason: str = "undone by the operator") -> PoseRecord | None:
        """Move the last recorded pose to ``set_aside`` (it is kept, not deleted)."""
        if not self.session.poses:
            return None
        record = self.session.poses.pop()
        self.session.set_aside.append(SetAside(step=record.step, reason=reason, pose=record))
        self.save()
        return record

    def set_aside_step(self, step: str, reason: str) -> int:
        """Move every recorded pose of ``step`` to ``set_aside`` (kept, with ``reason``); how
        many."""
        mine = [r for r in self.session.poses if r.step == step]
        if mine:
            self.session.poses = [r for r in self.session.poses if r.step != step]
            self.session.set_aside += [SetAside(step=step, reason=reason, pose=r) for r in mine]
            self.save()
        return len(mine)

    def recording_sink(self, run_start: float):
        """An ``on_record`` callback for :func:`hexcal.procedure.recording.record_procedure` that saves
        the session after every pose. ``run_start`` is the run's monotonic start (s): pose
        times continue the session's clock from its last pose (a resumed session's new run
        starts 1 s after it)."""
        last = max((r.t for r in self.session.poses), default=-1.0)
        offset = last + 1.0 - run_start if self.session.poses else -run_start
        ids: dict[int, int] = {}

        def sink(kind: str, step, pose: RecordedPose | None, reason: str) -> None:
            rec = None
            if pose is not None:
                try:
                    rec = self.session.pose_record(
                        pose, step.name, step.leg, step.constraint, t=round(pose.t + offset, 6)
                    )
                except SessionFileError as exc:
                    if kind != "refused":
                        raise
                    # A refused pose is kept for the record; one with a non-number keeps its
                    # reason only, since no valid record can hold it.
                    reason = f"{reason} (its values are not kept: {exc})"
            if kind == "pose":
                if rec is None:
                    raise SessionFileError(f"step {step.name}: a recorded pose came without values")
                ids[id(pose)] = rec.pose_id
                self.add_pose(rec)
            elif kind == "refused":
                self.set_aside(SetAside(step=step.name, reason=reason, pose=rec))
            elif kind == "set-aside":
                pid = ids.pop(id(pose))
                kept = [r for r in self.session.poses if r.pose_id == pid]
                self.session.poses = [r for r in self.session.poses if r.pose_id != pid]
                self.session.set_aside += [
                    SetAside(step=step.name, reason=reason, pose=r) for r in kept
                ]
                self.save()
            else:
                raise ValueError(f"unknown record kind {kind!r}")

        return sink

    def add_note(self, text: str) -> None:
        self.session.notes.append(OperatorNote(text=text))
        self.save()

    def add_result(self, result: ResultRecord) -> None:
        self.session.results.append(result)
        self.save()

    def add_progress(self, item: StepProgress) -> None:
        self.session.progress.append(item)
        self.save()


def latest_model(session: Session) -> ResultRecord | None:
    """The session's latest result that holds a model (a calibration or a diagnosis step)."""
    with_model = [r for r in session.results if r.calibrated is not None or r.robot is not None]
    return with_model[-1] if with_model else None


def export_session(session: Session, out: str | Path) -> list[str]:
    """Write the session as plain files into directory ``out`` (made if needed):
    ``measurements.csv`` (the interchange table), ``robot.json`` (the design),
    ``instruments.json`` (the noise, when the session holds it) and, when the
    session holds a model, ``calibrated.json``: the latest calibration or diagnosis step's whole
    model, effects included (docs/formats.md). The names written, in words."""
    from hexcal.io.measurements import write_measurements
    from hexcal.model.robot import save_robot

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_measurements(session.measurements(), out / "measurements.csv")
    save_robot(session.robot, out / "robot.json")
    written = ["measurements.csv", "robot.json"]
    if session.instruments is not None:
        from hexcal.model.instruments import save_instruments

        save_instruments(session.instruments, out / "instruments.json")
        written.append("instruments.json")
    latest = latest_model(session)
    if latest is not None:
        when = f"{latest.at:%Y-%m-%d %H:%M}"
        if latest.calibrated is not None:
            save_model(latest.calibrated, out / "calibrated.json")
            written.append(f"calibrated.json ({latest.calibrated.calibration.model}, {when})")
        elif latest.robot is not None:  # a session from before the model file: geometry only
            save_robot(latest.robot, out / "calibrated.json")
            written.append(f"calibrated.json (Model {latest.model} geometry, {when})")
    return written
