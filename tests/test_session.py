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

import numpy as np
import pytest

from hexcal.acquisition import LegSample, RecordedPose, TrackerSample
from hexcal.measurements import read_measurements, write_measurements
from hexcal.robot import load_robot
from hexcal.session import (
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
        ('{"schema_version": 99}', r"newer hexcal \(session schema 99; .* reads schema 2\)"),
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
    # Schema 2 reads schema 1 files (it only adds fields) and writes 2.
    assert version["enum"] == [1, SCHEMA_VERSION] and version["default"] == SCHEMA_VERSION
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
    from hexcal.session import Session, SessionFile
    from hexcal.study import left_hand
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
    sf = SessionFile.resume(path)
    n = len(sf.session.poses)
    assert n >= 1 and [p.pose_id for p in sf.session.poses] == list(range(1, n + 1))
    rng = np.random.default_rng(5)
    sf.add_pose(sf.session.pose_record(recorded_pose(rng), "free", 0, "free", t=1.0))
    assert len(load_session(path).poses) == n + 1
    # a kill mid-write leaves at most its one temporary file, never a damaged session
    assert len([q for q in tmp_path.iterdir() if q.name.endswith(".tmp")]) <= 1
