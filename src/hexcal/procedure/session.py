"""The session file: everything a calibration session recorded and computed, in one JSON file
(and, for a session imported from a table, the table's poses in a pose block beside it:
:mod:`hexcal.procedure.session_block`, which :func:`import_table` streams the table into).

A :class:`Session` (pydantic v2, in :mod:`hexcal.procedure.session_model` and importable from
here) holds the robot description, the device configuration, the procedure, every recorded pose
with its raw samples and timestamps, the poses refused or set aside (with the reason), operator
notes, and each calibration and diagnosis result with the model it used. ``schema_version`` says
which layout the file follows (``hexcal schema`` prints the JSON Schema).

Safety: :class:`SessionFile` saves the whole session atomically (temporary file, fsync, rename,
fsync of the directory) after every change, so a kill at any instant leaves either the previous
file or the new one. A file that is not valid JSON, not a session, or written by a newer hexcal
(higher ``schema_version``) is refused with a message naming it, and is never overwritten:
:class:`SessionFile` only writes to a path it created or loaded cleanly itself.

One writer: a :class:`SessionFile` holds the session's lock (:mod:`hexcal.procedure.session_lock`)
until it is closed, so a second program is refused, told who holds it; every save checks that the
file on disk is the one it last read or wrote, and refuses (:class:`SessionConflict`, both
versions kept, :mod:`hexcal.procedure.session_merge` merges them) when another program changed
it. The file is held to the rules of the table it exports to
(:mod:`hexcal.procedure.session_check`) on load and when a pose is added.

Numbers: every number in a session is finite and within the limits of :mod:`hexcal.io.safe_read`
(positions and readings ±1 km, times ±1e9 s, pose ids 1 .. 2**53 − 1). A pose holding NaN or
infinity is refused on construction (:class:`SessionFileError`), never saved. A file from an
older hexcal, which saved such values as ``null``, still loads: each pose with a ``null`` where a
number belongs is moved to ``set_aside`` whole (``unreadable_pose``), with a reason naming the pose
and the field; nothing else changes (:mod:`hexcal.procedure.session_legacy`).
"""

from __future__ import annotations

import hashlib
import json
import logging
import weakref
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from pydantic import ValidationError
from pydantic_core import PydanticSerializationError

from hexcal import __version__
from hexcal.acquire.acquisition import RecordedPose
from hexcal.effects.priors import check_priors
from hexcal.io.advice import beside, command, line
from hexcal.io.capacity import MAX_SESSION_BYTES, MB
from hexcal.io.fileio import (
    OutputFileError,
    remove_orphan_temp_files,
    write_files_atomic,
    write_text_atomic,
)
from hexcal.io.measurements import REQUIRED_COLUMNS
from hexcal.io.safe_read import KINDS, decode, parse_json, read_bytes
from hexcal.io.validation import format_validation_error, shown_value
from hexcal.model.robot import Robot
from hexcal.procedure import looks_like_session as looks_like_session
from hexcal.procedure.session_block import (
    attach,
    check_table_size,
    remove_stale_blocks,
    stream_table,
    write_block,
)
from hexcal.procedure.session_check import (
    duplicate_id_problems,
    pose_problems,
    problems_text,
    session_problems,
)
from hexcal.procedure.session_legacy import set_aside_null_poses
from hexcal.procedure.session_lock import SessionLock, SessionLocked, stale_notice
from hexcal.procedure.session_model import SCHEMA_VERSION as SCHEMA_VERSION
from hexcal.procedure.session_model import OperatorNote as OperatorNote
from hexcal.procedure.session_model import PoseRecord as PoseRecord
from hexcal.procedure.session_model import RawLegSample as RawLegSample
from hexcal.procedure.session_model import RawTrackerSample as RawTrackerSample
from hexcal.procedure.session_model import ResultRecord as ResultRecord
from hexcal.procedure.session_model import Session as Session
from hexcal.procedure.session_model import SessionFileError as SessionFileError
from hexcal.procedure.session_model import SetAside as SetAside
from hexcal.procedure.session_model import StepProgress as StepProgress

log = logging.getLogger(__name__)
# The notices are returned to the interface; logging is for an application that configures it
# (without a handler, Python would print the warnings over the text UI's screen).
log.addHandler(logging.NullHandler())


def session_json_schema() -> str:
    """The JSON Schema of the session file (``hexcal schema``)."""
    return json.dumps(Session.model_json_schema(), indent=2) + "\n"


def _error(message: str) -> SessionFileError:
    return SessionFileError(message)


def load_session(path: str | Path, notices: list[str] | None = None) -> Session:
    """Read a session file. Refuses — naming the file and saying what to do — a missing file,
    one that is not JSON or not a session, one beyond the limits of :mod:`hexcal.io.safe_read`
    (:data:`hexcal.io.capacity.MAX_SESSION_BYTES`, nesting, non-finite numbers, a key given
    twice), one written by a newer hexcal, and one whose poses break the rules of the table it
    exports to (a repeated pose id, a header without its columns:
    :mod:`hexcal.procedure.session_check`).

    Poses an older hexcal saved with ``null`` values are set aside (see the module docstring);
    each one's reason is appended to ``notices`` when given, and logged."""
    return _load(Path(path), notices)[0]


def _load(path: Path, notices: list[str] | None = None) -> tuple[Session, bytes]:
    """The session of ``path`` and the bytes it was read from (see :func:`load_session`)."""
    raw = read_bytes(path, "session", _error)
    data = parse_json(decode(raw, str(path), _error), str(path), _error, KINDS["session"].damaged)
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
    if session.pose_block is not None:  # read and checked now: a damaged block is refused
        attach(session, path.with_name(session.pose_block.file))
        session.imported()
    problems = session_problems(session)
    if problems:
        raise SessionFileError(
            problems_text(
                str(path),
                problems,
                "the file is left untouched; fix it there (the table it exports to must be "
                "valid) or start a new session",
            )
        )
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
    return session, raw


def session_to_text(session: Session) -> str:
    """The session file's text (indented JSON)."""
    return session.model_dump_json(indent=1, exclude_none=False) + "\n"


def _check_size(path: Path, text: str, creating: bool) -> None:
    """Refuse to write a session the readers would refuse: more than the session file's limit
    (:data:`hexcal.io.capacity.MAX_SESSION_BYTES`, the readers' own), named with the size."""
    size = len(text.encode("utf-8"))
    if size <= MAX_SESSION_BYTES:
        return
    what = (
        "the session file was not created; import a part of the table (a step, a stretch of "
        "time) per session, or calibrate straight from the table"
        if creating
        else "the last saved state is still on disk; record the rest in a new session"
    )
    raise SessionFileError(
        f"{path}: the session would take {size / MB:.0f} MB, more than the "
        f"{MAX_SESSION_BYTES // MB} MB a session file may have (what every hexcal command "
        f"reads); {what}"
    )


def _acquire(path: Path, creating: bool) -> SessionLock:
    """The session's lock, or :class:`SessionLocked` naming its holder; an OS error on the lock
    file (a folder one may not write in) in the user's terms."""
    try:
        return SessionLock.acquire(path)
    except SessionLocked:
        raise
    except OSError as exc:
        from hexcal.io.fileio import write_error

        err = write_error(exc, path)
        if creating:
            raise SessionFileError(f"{err}; the session file was not created") from None
        raise SessionFileError(
            f"{err}\nto record, this hexcal must lock the session beside it; to look at it, "
            "open it read-only (hexcal calibrate, diagnose and export only read it)"
        ) from None


def _release(lock: SessionLock | None) -> None:
    if lock is not None:
        lock.release()


class SessionConflict(SessionFileError):
    """The session file on disk is not the one this process last read or wrote: another
    program changed it. Nothing was overwritten; ``mine`` holds this process's version."""

    def __init__(self, message: str, mine: Path):
        super().__init__(message)
        self.mine = mine


@dataclass(frozen=True)
class _Seen:
    """The file on disk as this process last read or wrote it: its identity (inode, size,
    modification time in ns) and the SHA-256 of its bytes."""

    inode: int
    size: int
    mtime_ns: int
    sha256: str

    @classmethod
    def of(cls, path: Path, raw: bytes) -> _Seen | None:
        try:
            st = path.stat()
        except OSError:
            return None
        return cls(st.st_ino, st.st_size, st.st_mtime_ns, hashlib.sha256(raw).hexdigest())


class SessionFile:
    """A session bound to its file, with one writer; every change is saved atomically at once.

    Use :meth:`create` for a new file (refused if the path exists: an existing session is
    resumed, never replaced) and :meth:`resume` for an existing one (refused if damaged). Both
    take the session's lock (:mod:`hexcal.procedure.session_lock`) and hold it until
    :meth:`close` (or the end of a ``with`` block, or of the process): a second writer is
    refused with :class:`~hexcal.procedure.session_lock.SessionLocked`, naming the holder.
    ``resume(path, read_only=True)`` opens without the lock, and refuses to save.

    Every save first checks that the file on disk is the one this process last read or wrote
    (its identity, else its SHA-256): when another program changed it, the save refuses with
    :class:`SessionConflict`, keeps the file on disk as it is and writes this process's version
    beside it (:meth:`conflict_path`), so that nothing is lost."""

    def __init__(
        self,
        path: Path,
        session: Session,
        notices: Sequence[str] = (),
        *,
        lock: SessionLock | None = None,
        read_only: bool = False,
        seen: _Seen | None = None,
    ):
        self.path = path
        self.session = session
        #: What opening the file did, in words (orphan temporary files removed, poses set
        #: aside on load, a crashed holder's lock taken over), for the interface to show.
        self.notices: list[str] = list(notices)
        self.read_only = read_only
        self._lock = lock
        self._seen = seen
        # The lock goes with the object if nobody closes it (a test, an interface that fails).
        self._finalizer = weakref.finalize(self, _release, lock)

    @classmethod
    def create(
        cls, path: str | Path, session: Session, fill: Callable[[Path], object] | None = None
    ) -> SessionFile:
        """A new session file at ``path``. ``fill(path)``, when given, runs once the lock is
        held and before the first save (``session import`` streams its table into the pose
        block there); whatever it or the save wrote is removed when either fails."""
        path = Path(path)
        lock = _acquire(path, creating=True)
        before = session._block_path
        try:
            if path.exists():
                raise SessionFileError(
                    f"{path}: already exists — resume it, or choose another name; it is not "
                    "overwritten"
                )
            if fill is not None:
                fill(path)
            sf = cls(path, session, lock=lock)
            sf.save(creating=True)
        except BaseException:
            new = session._block_path
            if new is not None and new != before:
                new.unlink(missing_ok=True)
            lock.release()
            raise
        sf._tidy_blocks()
        return sf

    @classmethod
    def resume(cls, path: str | Path, read_only: bool = False) -> SessionFile:
        """Open an existing session to go on with it (``read_only``: to look at it, without
        the lock; saving is then refused). Once it has loaded, the temporary files an
        interrupted save left next to it (named as :func:`hexcal.io.fileio.write_text_atomic`
        names them, for this file only) are removed and said so in :attr:`notices`; a file
        that does not load is refused with everything next to it left as it is."""
        path = Path(path)
        notices: list[str] = []
        lock = None if read_only else _acquire(path, creating=False)
        try:
            session, raw = _load(path, notices)
        except BaseException:
            _release(lock)
            raise
        if lock is not None and lock.taken_over is not None:
            text = stale_notice(path, lock.taken_over)
            log.warning("%s", text)
            notices.append(text)
        if lock is not None:  # only the writer may tidy up after an interrupted save
            for tmp, size in remove_orphan_temp_files(path):
                text = (
                    f"{tmp}: removed, a temporary file ({size} bytes) an interrupted save "
                    f"left; {path.name} holds the last complete save"
                )
                log.warning("%s", text)
                notices.append(text)
        sf = cls(path, session, notices, lock=lock, read_only=read_only, seen=_Seen.of(path, raw))
        if lock is not None:
            sf._tidy_blocks()
        return sf

    def _tidy_blocks(self) -> None:
        """Remove the pose blocks of this file's name that no session names (holding the lock):
        said in :attr:`notices` and logged."""
        keep = self.session.pose_block.file if self.session.pose_block is not None else None
        for block in remove_stale_blocks(self.path, keep):
            text = (
                f"{block}: removed, a pose block of {self.path.name} that neither it nor any "
                "other file beside it names (its session file was deleted or replaced)"
            )
            log.warning("%s", text)
            self.notices.append(text)

    def close(self) -> None:
        """Give up the session's lock (saving stays possible only for a read-only look: no)."""
        self._finalizer()
        self._lock = None
        self.read_only = True

    def __enter__(self) -> SessionFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def conflict_path(self) -> Path:
        """Where a save that met another program's change puts this process's version."""
        return self.path.with_name(f"{self.path.stem}.mine{self.path.suffix or '.json'}")

    def _check_disk(self) -> None:
        """Refuse to save over a file another program changed since this one read or wrote it
        (:class:`SessionConflict`, this version written to :meth:`conflict_path`)."""
        seen = self._seen
        if seen is None:
            return
        try:
            st = self.path.stat()
            if (st.st_ino, st.st_size, st.st_mtime_ns) == (seen.inode, seen.size, seen.mtime_ns):
                return
            raw = read_bytes(self.path, "session", _error)
            if hashlib.sha256(raw).hexdigest() == seen.sha256:
                return
            what = "changed"
        except FileNotFoundError:
            what = "removed"
        except (OSError, SessionFileError):
            what = "made unreadable"
        mine = self.conflict_path()
        write_text_atomic(mine, session_to_text(self.session))
        merged = beside(self.path, "merged", self.path.suffix)
        raise SessionConflict(
            f"{self.path}: {what} by another program since this hexcal opened it, so it is not "
            f"overwritten. Nothing is lost: the file there holds the other program's work, and "
            f"{mine} holds this session as it is here. To merge them:\n"
            + line(command("session", "merge", self.path, mine, "--out", merged)),
            mine,
        )

    def save(self, creating: bool = False) -> None:
        if self.read_only:
            raise SessionFileError(
                f"{self.path}: opened read-only (or closed): nothing is saved; resume it to record"
            )
        # A schema 1 or 2 file is upgraded when hexcal writes it (later schemas only add fields).
        self.session.schema_version = SCHEMA_VERSION
        old = (self.session.pose_block, self.session._block_path)
        try:
            # The pose block first (a new file, named by its checksum), then the file naming it.
            new_block = write_block(self.session, self.path)
        except OutputFileError as exc:
            raise SessionFileError(str(exc) + _unsaved(creating)) from None
        try:
            self._write(creating)
        except BaseException:
            if new_block is not None:
                new_block.unlink(missing_ok=True)
                self.session.pose_block, self.session._block_path = old
            raise

    def _write(self, creating: bool) -> None:
        text = session_to_text(self.session)
        _check_size(self.path, text, creating)
        if not creating:
            self._check_disk()
        try:
            write_text_atomic(self.path, text)
        except OutputFileError as exc:
            if creating:
                raise SessionFileError(f"{exc}; the session file was not created") from None
            raise SessionFileError(
                f"{exc}\nthe last saved state is still on disk; the change made now is not "
                "saved: fix the cause, then do it again"
            ) from None
        self._seen = _Seen.of(self.path, text.encode("utf-8"))

    def add_pose(self, record: PoseRecord) -> None:
        """Append a recorded pose and save. The record is checked again as loading would
        check it (finite numbers in range, an unused pose id, the table's rules): a record
        built without validation, or changed after, is refused naming the session file, the
        pose and the field, and nothing is saved."""
        record = self._checked(record)
        if record.temperature is not None and "temperature" not in self.session.columns:
            # The table's temperature column comes with the first pose that has one (the
            # poses before it export an empty cell); it sits after the required columns.
            cols = self.session.columns
            at = max(cols.index(c) for c in REQUIRED_COLUMNS) + 1
            self.session.columns = [*cols[:at], "temperature", *cols[at:]]
        self.session.poses.append(record)
        self.save()

    def _checked(self, record: PoseRecord) -> PoseRecord:
        where = f"{self.path}: pose {getattr(record, 'pose_id', '?')} not saved"
        try:
            data = record.model_dump()
        except PydanticSerializationError:  # built without validation: a field of a wrong type
            data = {name: getattr(record, name, None) for name in PoseRecord.model_fields}
        try:
            checked = PoseRecord.model_validate(data)
        except ValidationError as exc:
            raise SessionFileError(
                format_validation_error(exc, where)
                + "\na pose must hold finite numbers in range: check the devices, then "
                "record the pose again"
            ) from None
        i = len(self.session.poses)
        problems = duplicate_id_problems([*self.session.poses, checked])
        table = self.session.imported()
        if table is not None and checked.pose_id in table.pose_id:
            problems.append(
                f"pose {checked.pose_id}: the id is an imported pose's; give it an unused id"
            )
        problems += pose_problems(checked, i, self.session.columns)
        if problems:
            raise SessionFileError(problems_text(where, problems, "the session is unchanged"))
        return checked

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
        counts = [0] * 6  # the encoders' reboots at the run's last pose (the driver's from 0)

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
                if pose is not None:
                    self._mark_reboots(pose, rec, counts)
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

    def _mark_reboots(self, pose: RecordedPose, rec: PoseRecord, counts: list[int]) -> None:
        """The legs whose encoder rebooted since the run's last pose (``counts``, updated):
        each is checked against the tracker's pose and the model, marked on ``rec`` and in the
        session (:mod:`hexcal.procedure.reboots`), and logged."""
        from hexcal.procedure.reboots import check_reboot, reboot_counts, reboot_note

        now = reboot_counts(pose)
        for k, n in enumerate(now[:6]):
            if n > counts[k]:
                found = check_reboot(self.session, rec, k + 1, float(pose.reading_spread_mm))
                self.session.encoder_reboots.append(found)
                rec.notes.append(reboot_note(found))
                log.warning("%s: %s", self.path, rec.notes[-1])
                counts[k] = n

    def add_note(self, text: str) -> None:
        self.session.notes.append(OperatorNote(text=text))
        self.save()

    def add_result(self, result: ResultRecord) -> None:
        self.session.results.append(result)
        self.save()

    def add_progress(self, item: StepProgress) -> None:
        self.session.progress.append(item)
        self.save()


def import_table(
    source: str | Path, robot: Robot, out: str | Path, notices: list[str] | None = None
) -> tuple[Path, int]:
    """``session import``: a new session file ``out`` holding the table ``source`` in a pose
    block, streamed (memory does not grow with the table). The session file's path and the
    number of poses; refused, with nothing written, when ``out`` exists, the table is bad or
    beyond :data:`~hexcal.io.capacity.MAX_IMPORTED_POSES` (that before anything is written,
    even the lock)."""
    source, out = Path(source), Path(out)
    check_table_size(source, out)  # before the lock, the block or the session file
    session = Session(robot=robot)
    count: list[int] = []

    def fill(path: Path) -> None:
        count.append(stream_table(source, session, path, notices))

    with SessionFile.create(out, session, fill=fill) as sf:
        return sf.path, count[0]


def _unsaved(creating: bool) -> str:
    if creating:
        return "; the session file was not created"
    return "\nthe last saved state is still on disk; fix the cause, then do it again"


def latest_model(session: Session) -> ResultRecord | None:
    """The session's latest result that holds a model (a calibration or a diagnosis step)."""
    with_model = [r for r in session.results if r.calibrated is not None or r.robot is not None]
    return with_model[-1] if with_model else None


def export_session(session: Session, out: str | Path) -> list[str]:
    """Write the session as plain files into directory ``out`` (made if needed):
    ``measurements.csv`` (the interchange table), ``robot.json`` (the design),
    ``instruments.json`` (the noise, when the session holds it) and, when the
    session holds a model, ``calibrated.json``: the latest calibration or diagnosis step's whole
    model, effects included (docs/formats.md). The names written, in words.

    Every file's text is made first (a session that cannot give a valid table is refused
    naming the session's poses and fields), then all are written in one step
    (:func:`~hexcal.io.fileio.write_files_atomic`): a refused or failed export leaves nothing
    behind."""
    from hexcal.io.measurements import measurements_csv_pieces

    problems = session_problems(session)
    if problems:
        raise SessionFileError(
            problems_text("the session", problems, "nothing was exported; fix the session file")
        )
    # The table is written a part at a time: a session of millions of poses exports without
    # its whole text in memory.
    files: dict[str, str | Iterable[str]] = {
        "measurements.csv": measurements_csv_pieces(session.measurements()),
        "robot.json": session.robot.to_json(),
    }
    written = ["measurements.csv", "robot.json"]
    if session.instruments is not None:
        files["instruments.json"] = session.instruments.to_json()
        written.append("instruments.json")
    latest = latest_model(session)
    if latest is not None:
        when = f"{latest.at:%Y-%m-%d %H:%M}"
        if latest.calibrated is not None:
            files["calibrated.json"] = latest.calibrated.to_json()
            written.append(f"calibrated.json ({latest.calibrated.calibration.model}, {when})")
        elif latest.robot is not None:  # a session from before the model file: geometry only
            files["calibrated.json"] = latest.robot.to_json()
            written.append(f"calibrated.json (Model {latest.model} geometry, {when})")
    write_files_atomic(out, files)
    return written
