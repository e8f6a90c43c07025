"""The session file: lossless import/export, refusal of damaged or newer files (never
overwritten), atomic saves that survive a kill at any instant."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from hexcal.acquire.acquisition import LegSample, RecordedPose, TrackerSample
from hexcal.estimate.model_file import load_robot
from hexcal.io.measurements import write_measurements
from hexcal.io.measurements_csv import read_measurements
from hexcal.procedure.session import (
    SCHEMA_VERSION,
    Session,
    SessionFile,
    SessionFileError,
    load_session,
    looks_like_session,
    session_json_schema,
)

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "left-hand-sim"


def recorded_pose(rng, n=5) -> RecordedPose:
    ts = [
        TrackerSample(float(i), rng.normal(size=3), np.array([1.0, 0, 0, 0]), 0.01)
        for i in range(n)
    ]
    ts.append(TrackerSample(9.0, None, None, fault="tool 01 MISSING"))
    ls = [LegSample(float(i), rng.normal(size=6)) for i in range(n)]
    ls.append(LegSample(9.5, np.r_[rng.normal(size=5), np.nan], ("leg 6 sent no position",)))
    return RecordedPose(
        1.0, rng.normal(size=3), np.array([1.0, 0, 0, 0]), rng.normal(size=6), ts, ls
    )


def test_interchange_csv_round_trips_through_a_session_file(tmp_path):
    meas = read_measurements(EXAMPLE / "measurements.csv")
    sess = Session.from_measurements(meas, load_robot(EXAMPLE / "robot.json"))
    sf = SessionFile.create(tmp_path / "s.json", sess)
    back = load_session(sf.path).measurements()
    assert back == meas
    write_measurements(back, tmp_path / "out.csv")
    assert (tmp_path / "out.csv").read_bytes() == (EXAMPLE / "measurements.csv").read_bytes()


def test_raw_samples_are_kept_faults_and_missing_values_included(tmp_path, design):
    rng = np.random.default_rng(0)
    sf = SessionFile.create(tmp_path / "s.json", Session(robot=design))
    pose = recorded_pose(rng)
    sf.add_pose(sf.session.pose_record(pose, "leg2-length", 2, "length", t=3.5))
    got = load_session(sf.path).poses[0]
    assert got.pose_id == 1 and got.step == "leg2-length" and got.t == 3.5
    assert got.position == pose.position.tolist()
    assert len(got.tracker_samples) == 6 and got.tracker_samples[-1].fault == "tool 01 MISSING"
    assert got.tracker_samples[-1].position is None
    assert got.leg_samples[-1].readings[5] is None and got.leg_samples[-1].faults
    assert got.leg_samples[0].readings == pose.leg_samples[0].readings.tolist()


def test_undo_keeps_the_pose_aside(tmp_path, design):
    rng = np.random.default_rng(1)
    sf = SessionFile.create(tmp_path / "s.json", Session(robot=design))
    for _ in range(2):
        sf.add_pose(sf.session.pose_record(recorded_pose(rng), "free", 0, "free", t=0.0))
    undone = sf.undo_last_pose()
    s = load_session(sf.path)
    assert [p.pose_id for p in s.poses] == [1]
    assert s.set_aside[0].pose.pose_id == undone.pose_id == 2
    # numbering never reuses an id, even of a pose set aside
    assert s.next_pose_id() == 3


def test_create_never_replaces_an_existing_file(tmp_path, design):
    p = tmp_path / "s.json"
    p.write_text("precious")
    with pytest.raises(SessionFileError, match="already exists — resume it"):
        SessionFile.create(p, Session(robot=design))
    assert p.read_text() == "precious"


@pytest.mark.parametrize(
    "text, match",
    [
        (
            '{"schema_version": 1, "robot": ',
            r"line 1, column \d+: not valid JSON .* left untouched",
        ),
        ("[1, 2]", "not a hexcal session file"),
        ('{"schema_version": 99}', r"newer hexcal \(session schema 99; .* reads schema 3\)"),
        ('{"schema_version": 1, "robot": {}}', r"field robot\.\w+: Field required"),
    ],
)
def test_damaged_or_newer_files_are_refused_and_left_untouched(tmp_path, text, match):
    p = tmp_path / "s.json"
    p.write_text(text)
    with pytest.raises(SessionFileError, match=match) as err:
        SessionFile.resume(p)
    assert str(p) in str(err.value)
    assert p.read_text() == text


def test_schema_is_printed_and_versioned():
    schema = json.loads(session_json_schema())
    version = schema["properties"]["schema_version"]
    # Schema 3 reads schema 1 and 2 files (each only adds fields) and writes 3.
    assert version["enum"] == [1, 2, SCHEMA_VERSION] and version["default"] == SCHEMA_VERSION
    assert SCHEMA_VERSION == 3 and "pose_block" in schema["properties"]
    assert "calibrated" in schema["$defs"]["ResultRecord"]["properties"]
    assert "poses" in schema["properties"]


def test_looks_like_session(tmp_path, design):
    sf = SessionFile.create(tmp_path / "s.json", Session(robot=design))
    assert looks_like_session(sf.path)
    assert not looks_like_session(EXAMPLE / "measurements.csv")
    assert not looks_like_session(EXAMPLE / "robot.json")


WRITER = textwrap.dedent(
    """
    import sys, numpy as np
    sys.path.insert(0, {tests!r})
    from test_session import recorded_pose
    from hexcal.procedure.session import Session, SessionFile
    from hexcal.sim.robots import left_hand
    rng = np.random.default_rng(0)
    sf = SessionFile.create(sys.argv[1], Session(robot=left_hand()))
    print("ready", flush=True)
    while True:
        sf.add_pose(sf.session.pose_record(recorded_pose(rng, 50), "free", 0, "free", t=0.0))
    """
)


@pytest.mark.parametrize("delay_s", [0.3, 0.77, 1.31])
def test_a_kill_while_recording_leaves_the_session_intact_and_resumable(tmp_path, delay_s):
    """SIGKILL a process that saves a pose after pose: whatever instant it dies, the file on
    disk is a whole session (the last pose saved, or the one before), and recording resumes."""
    path = tmp_path / "killed.json"
    code = WRITER.format(tests=str(Path(__file__).parent))
    proc = subprocess.Popen([sys.executable, "-c", code, str(path)], stdout=subprocess.PIPE)
    assert proc.stdout.readline().strip() == b"ready"
    time.sleep(delay_s)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    # a kill mid-write leaves at most its one temporary file, never a damaged session
    left = [q for q in tmp_path.iterdir() if q.name.endswith(".tmp")]
    assert len(left) <= 1
    sf = SessionFile.resume(path)
    n = len(sf.session.poses)
    assert n >= 1 and [p.pose_id for p in sf.session.poses] == list(range(1, n + 1))
    # resuming removes it, and says so; the killed writer's lock is taken over, and said so
    assert [q for q in tmp_path.iterdir() if q.name.endswith(".tmp")] == []
    removed = [n for n in sf.notices if "an interrupted save left" in n]
    assert len(removed) == len(left)
    taken = [n for n in sf.notices if "took over the lock of process" in n]
    assert len(taken) == 1 and f"process {proc.pid} " in taken[0]
    rng = np.random.default_rng(5)
    sf.add_pose(sf.session.pose_record(recorded_pose(rng), "free", 0, "free", t=1.0))
    assert len(load_session(path).poses) == n + 1


# -- numbers: finite on the way in, null poses of older files set aside on load -------------------

NULL_POSE = Path(__file__).parent / "data" / "session-null-pose.json"


def test_a_session_with_a_null_pose_from_an_older_hexcal_loads_with_it_set_aside(tmp_path):
    """An older hexcal saved NaN as null: the file loads, the pose moves to set_aside whole,
    with a reason naming the pose and the fields; nothing else changes."""
    path = tmp_path / "old.json"
    path.write_bytes(NULL_POSE.read_bytes())
    before = json.loads(NULL_POSE.read_text())
    sf = SessionFile.resume(path)
    s = sf.session
    assert [p.pose_id for p in s.poses] == [1]
    assert s.poses[0].model_dump(mode="json") == before["poses"][0]
    assert len(s.set_aside) == 1
    aside = s.set_aside[0]
    assert aside.pose is None and aside.unreadable_pose == before["poses"][1]
    assert aside.reason == (
        "pose 2: position.0, readings.5 were not numbers (saved by an older hexcal); "
        "set aside on load"
    )
    assert sf.notices == [f"{path}: {aside.reason}"]
    # The robot as it was (keys added to robot.json since that hexcal default to null).
    assert s.robot.model_dump(mode="json", exclude_none=True) == {
        k: v for k, v in before["robot"].items() if v is not None
    }
    assert s.next_pose_id() == 3  # the set-aside pose's id is never reused
    # Saved again, the pose stays aside as it was, and the file loads cleanly.
    sf.save()
    again = load_session(path)
    assert again.set_aside[0].unreadable_pose == before["poses"][1]
    assert [p.pose_id for p in again.poses] == [1]


def test_a_set_aside_pose_with_nulls_is_kept_whole(tmp_path):
    data = json.loads(NULL_POSE.read_text())
    pose = data["poses"].pop()
    data["set_aside"] = [{"step": pose["step"], "reason": "undone", "pose": pose}]
    path = tmp_path / "old.json"
    path.write_text(json.dumps(data))
    s = load_session(path)
    assert s.set_aside[0].pose is None and s.set_aside[0].unreadable_pose == pose
    assert s.set_aside[0].reason.startswith("undone — pose 2: position.0, readings.5")


@pytest.mark.parametrize("field", ["position", "quaternion", "readings"])
def test_a_pose_holding_nan_or_inf_is_refused_not_saved(tmp_path, design, field):
    rng = np.random.default_rng(2)
    sf = SessionFile.create(tmp_path / "s.json", Session(robot=design))
    pose = recorded_pose(rng)
    getattr(pose, field)[1] = np.inf if field == "readings" else np.nan
    with pytest.raises(SessionFileError, match=rf"field {field}\.1: .*finite number") as err:
        sf.session.pose_record(pose, "free", 0, "free", t=0.0)
    assert "record the pose again" in str(err.value)
    assert "errors.pydantic.dev" not in str(err.value)
    assert load_session(sf.path).poses == []


def test_a_raw_sample_with_a_non_number_is_saved_as_none_and_flagged():
    from hexcal.procedure.session import RawLegSample, RawTrackerSample

    s = RawTrackerSample.of(TrackerSample(1.0, np.array([1.0, np.nan, 0]), np.ones(4) / 2, 0.1))
    assert s.position is None and s.quaternion == [0.5] * 4
    assert s.fault == "the tracker's position was not a number"
    legs = RawLegSample.of(LegSample(1.0, np.array([1.0, np.inf, 2e6, 4, 5, 6])))
    assert legs.readings == [1.0, None, None, 4.0, 5.0, 6.0]
    assert legs.faults == ["leg 2, 3: the reading was not a number"]


def test_pose_ids_are_bounded(design):
    from pydantic import ValidationError

    from hexcal.procedure.session import PoseRecord

    row = dict(
        t=0.0,
        step="free",
        leg=0,
        constraint="free",
        position=[0, 0, 0],
        quaternion=[1, 0, 0, 0],
        readings=[0] * 6,
    )
    assert PoseRecord(pose_id=2**53 - 1, **row).pose_id == 2**53 - 1
    for bad in (0, 2**53, 10**30):
        with pytest.raises(ValidationError):
            PoseRecord(pose_id=bad, **row)


# -- temporary files an interrupted save left ---------------------------------------------------


def test_resume_removes_the_orphan_temporary_files_of_that_session_only(tmp_path, design):
    SessionFile.create(tmp_path / "s.json", Session(robot=design)).close()
    ours = [tmp_path / ".s.json.a1b2_c3d.tmp", tmp_path / ".s.json.zzzzzzzz.tmp"]
    for p in ours:
        p.write_bytes(b"x" * 100)
    others = [
        tmp_path / ".other.json.a1b2c3d4.tmp",  # another file's
        tmp_path / "s.json.tmp",  # not hexcal's naming
        tmp_path / ".s.json.short.tmp",  # not 8 random characters
        tmp_path / ".s.json.ABCDEFGH.tmp",  # mkstemp's characters are lower case
        tmp_path / ".s.json.a1b2c3d4.tmp.bak",
    ]
    for p in others:
        p.write_text("keep")
    (tmp_path / ".s.json.dirdirdi.tmp").mkdir()  # not a regular file
    resumed = SessionFile.resume(tmp_path / "s.json")
    assert not any(p.exists() for p in ours)
    assert all(p.exists() for p in others) and (tmp_path / ".s.json.dirdirdi.tmp").is_dir()
    assert len(resumed.notices) == 2
    assert all("100 bytes" in n and "interrupted save" in n for n in resumed.notices)
    resumed.close()
    assert SessionFile.resume(tmp_path / "s.json").notices == []


def test_a_session_that_does_not_load_keeps_its_temporary_files(tmp_path):
    path = tmp_path / "s.json"
    path.write_text('{"schema_version": 2, "robot": ')
    tmp = tmp_path / ".s.json.abcdefgh.tmp"
    tmp.write_text("perhaps the newer state")
    with pytest.raises(SessionFileError, match="not valid JSON"):
        SessionFile.resume(path)
    assert tmp.read_text() == "perhaps the newer state"


def test_the_writer_refuses_what_the_readers_would_and_names_the_limit(tmp_path, monkeypatch):
    """One limit, read by the readers and the writer alike: a session beyond it is never
    written (here the limit lowered to 50 KB for a 93 KB session), and neither a file nor a
    lock is left."""
    import hexcal.procedure.session as session_module
    from hexcal.io import capacity
    from hexcal.io.safe_read import KINDS

    assert KINDS["session"].max_bytes == capacity.MAX_SESSION_BYTES
    assert session_module.MAX_SESSION_BYTES == capacity.MAX_SESSION_BYTES
    meas = read_measurements(EXAMPLE / "measurements.csv")
    monkeypatch.setattr(session_module, "MAX_SESSION_BYTES", 50 * 1024)
    monkeypatch.setattr(session_module, "MB", 1024)  # the sizes said in KB, as they are
    path = tmp_path / "s.json"
    with pytest.raises(SessionFileError) as exc:
        SessionFile.create(
            path, Session.from_measurements(meas, load_robot(EXAMPLE / "robot.json"))
        )
    assert str(exc.value).startswith(f"{path}: the session would take 9")
    assert "more than the 50 MB a session file may have" in str(exc.value)  # (KB, as lowered)
    assert "was not created" in str(exc.value)
    assert list(tmp_path.iterdir()) == []


def test_import_refuses_a_table_beyond_what_a_session_holds_before_writing(
    tmp_path, monkeypatch, capsys
):
    from hexcal.app.cli import main
    from hexcal.io import capacity

    monkeypatch.setattr(capacity, "MAX_IMPORTED_POSES", 100)
    out = tmp_path / "s.json"
    args = [
        "session",
        "import",
        str(EXAMPLE / "measurements.csv"),
        "--robot",
        str(EXAMPLE / "robot.json"),
    ]
    assert main([*args, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    # Refused before anything is written, naming the count: no session file, no pose block,
    # no temporary file and no lock are left.
    assert "184 poses; a session holds at most 100 imported poses" in err
    assert "hexcal.io.capacity.MAX_IMPORTED_POSES" in err
    assert f"{out} was not written" in err and list(tmp_path.iterdir()) == []


def test_a_failed_write_is_a_session_error_and_the_saved_state_stays(tmp_path, design, monkeypatch):
    """The disk refusing the session file (here the writer raising what a full disk gives)
    reaches the caller as a SessionFileError saying the last saved state is still on disk, and
    that state loads as it was; a new file that cannot be written says it was not created."""
    from hexcal.io.fileio import OutputFileError
    from hexcal.procedure import session as session_module

    sf = SessionFile.create(tmp_path / "s.json", Session(robot=design))
    sf.add_note("before")

    def full(path, text, *a, **k):
        raise OutputFileError(f"{path}: no space left on the device", path)

    monkeypatch.setattr(session_module, "write_text_atomic", full)
    with pytest.raises(SessionFileError, match="the last saved state is still on disk"):
        sf.add_note("after")
    assert [n.text for n in load_session(sf.path).notes] == ["before"]
    with pytest.raises(SessionFileError, match="the session file was not created"):
        SessionFile.create(tmp_path / "new.json", Session(robot=design))
    monkeypatch.undo()
    # The pose block (written before the file naming it) refused alike.
    monkeypatch.setattr(session_module, "write_block", lambda s, path: full(path, ""))
    with pytest.raises(SessionFileError, match="the last saved state is still on disk"):
        sf.add_note("after")
    assert [n.text for n in load_session(sf.path).notes] == ["before"]


def test_a_temperature_column_comes_after_the_required_ones_in_the_export(tmp_path, design):
    """The first pose with a temperature adds the column after the interchange table's
    required columns (docs/formats.md's order), and the export writes that header."""
    from hexcal.io.measurements import REQUIRED_COLUMNS
    from hexcal.procedure.session import export_session

    rng = np.random.default_rng(3)
    sf = SessionFile.create(tmp_path / "s.json", Session(robot=design))
    for t, temp in [(0.0, 20.0), (1.0, 21.5)]:
        pose = sf.session.pose_record(recorded_pose(rng), "free", 0, "free", t=t, temperature=temp)
        sf.add_pose(pose)
    want = [*REQUIRED_COLUMNS, "temperature"]
    assert load_session(sf.path).columns == want
    export_session(load_session(sf.path), tmp_path / "out")
    header = (tmp_path / "out" / "measurements.csv").read_text().splitlines()
    assert next(h for h in header if not h.startswith("#")).split(",") == want


def test_the_export_writes_the_latest_of_several_models(tmp_path, design):
    """Three results holding a model, each a robot scaled differently: calibrated.json is the
    last one's (the time written beside it), whatever their number."""
    from datetime import UTC, datetime

    from hexcal.procedure.session import export_session
    from hexcal.procedure.session_model import ResultRecord

    rng = np.random.default_rng(4)
    sf = SessionFile.create(tmp_path / "s.json", Session(robot=design))
    sf.add_pose(sf.session.pose_record(recorded_pose(rng), "free", 0, "free", t=0.0))
    for k, mass in enumerate([11.0, 12.0, 13.0]):
        robot = design.model_copy(update={"platform_mass_kg": mass})
        at = datetime(2026, 11, 28, 9 + k, 0, tzinfo=UTC)
        sf.add_result(ResultRecord(kind="calibration", model=42, robot=robot, at=at))
    written = export_session(load_session(sf.path), tmp_path / "out")
    assert written[-1] == "calibrated.json (Model 42 geometry, 2026-11-28 11:00)"
    assert load_robot(tmp_path / "out" / "calibrated.json").platform_mass_kg == 13.0


def test_a_refused_pose_is_set_aside_and_a_pose_with_a_non_number_names_it(tmp_path, design):
    """Through the recording sink: a refused pose goes to set_aside with its reason, not to the
    poses; a pose whose reading is NaN is refused naming the reading, nothing saved."""
    rng = np.random.default_rng(5)
    sf = SessionFile.create(tmp_path / "s.json", Session(robot=design))
    sink = sf.recording_sink(run_start=0.0)
    step = SimpleNamespace(name="leg1-length", leg=1, constraint="length")
    sink("pose", step, recorded_pose(rng), "")
    sink("refused", step, recorded_pose(rng), "the tracker lost the tool")
    s = load_session(sf.path)
    assert [p.pose_id for p in s.poses] == [1]
    assert [(a.step, a.reason) for a in s.set_aside] == [
        ("leg1-length", "the tracker lost the tool")
    ]
    bad = recorded_pose(rng)
    bad.readings[2] = np.nan
    with pytest.raises(SessionFileError, match="readings") as err:
        sink("pose", step, bad, "")
    assert "without values" not in str(err.value)
    assert len(load_session(sf.path).poses) == 1


def test_a_recorded_pose_set_aside_later_moves_alone_with_its_reason(tmp_path, design):
    """Through the recording sink: three poses recorded, then the second set aside (its step's
    check failed): it alone moves to set_aside, with the reason; the first and third stay."""
    rng = np.random.default_rng(7)
    sf = SessionFile.create(tmp_path / "s.json", Session(robot=design))
    sink = sf.recording_sink(run_start=0.0)
    step = SimpleNamespace(name="leg3-length", leg=3, constraint="length")
    poses = [recorded_pose(rng) for _ in range(3)]
    for pose in poses:
        sink("pose", step, pose, "")
    sink("set-aside", step, poses[1], "the clamp slipped")
    s = load_session(sf.path)
    assert [p.pose_id for p in s.poses] == [1, 3]
    assert [(a.step, a.reason, a.pose.pose_id) for a in s.set_aside] == [
        ("leg3-length", "the clamp slipped", 2)
    ]


def test_a_rebooted_encoder_is_noted_on_its_pose_and_logged_with_that_note(
    tmp_path, design, caplog
):
    """Leg 2's encoder reports one reboot at the second pose (the pose also carries a flagged
    sample's note): the pose's last note names leg 2's reboot, and the warning logged is
    that note, not the pose's other one."""
    import dataclasses
    import logging

    rng = np.random.default_rng(6)
    sf = SessionFile.create(tmp_path / "s.json", Session(robot=design))
    sink = sf.recording_sink(run_start=0.0)
    step = SimpleNamespace(name="free", leg=0, constraint="free")
    sink("pose", step, recorded_pose(rng), "")
    pose = recorded_pose(rng)
    pose = dataclasses.replace(
        pose,
        notes=("leg 6 sent no position in one set",),
        leg_samples=[dataclasses.replace(s, reboots=(0, 1, 0, 0, 0, 0)) for s in pose.leg_samples],
    )
    with caplog.at_level(logging.WARNING):
        sink("pose", step, pose, "")
    notes = load_session(sf.path).poses[-1].notes
    assert notes[0] == "leg 6 sent no position in one set"
    assert notes[-1].startswith("leg 2's encoder rebooted before this pose (pose 2)")
    assert [r.getMessage() for r in caplog.records if "rebooted" in r.getMessage()] == [
        f"{sf.path}: {notes[-1]}"
    ]
