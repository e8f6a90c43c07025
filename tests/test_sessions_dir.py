"""The sessions directory: where it is, how a new session is named, and the list the start
screen offers to resume (a damaged file listed with what is wrong, never hidden)."""

from __future__ import annotations

import os
from pathlib import Path

from hexcal.model.robot import Robot
from hexcal.procedure.session import Session, SessionFile
from hexcal.procedure.sessions_dir import (
    ENV,
    list_sessions,
    new_session_path,
    sessions_dir,
)
from hexcal.sim.robots import left_hand


def test_the_directory_is_the_option_then_the_environment_then_the_user_data_dir(monkeypatch):
    monkeypatch.setenv(ENV, "/labs/sessions")
    assert sessions_dir("~/mine") == Path("~/mine").expanduser()
    assert sessions_dir() == Path("/labs/sessions")
    monkeypatch.delenv(ENV)
    default = sessions_dir()
    assert default.parts[-2:] == ("hexcal", "sessions") and default.is_absolute()


def test_a_new_session_is_named_by_its_start_time_and_never_takes_a_used_name(tmp_path):
    first = new_session_path(tmp_path, now=0.0)
    assert first.parent == tmp_path and first.name.startswith("hexcal-session-")
    first.write_text("{}")
    second = new_session_path(tmp_path, now=0.0)
    assert second != first and second.name.endswith("-2.json")


def _session(path: Path, robot: Robot) -> None:
    SessionFile.create(path, Session(robot=robot))


def test_sessions_are_listed_newest_first_with_robot_poses_and_last_step(tmp_path):
    from hexcal.io.measurements_csv import read_measurements

    meas = read_measurements(Path(__file__).parents[1] / "examples/left-hand-sim/measurements.csv")
    old, new = tmp_path / "old.json", tmp_path / "new.json"
    _session(old, left_hand())
    SessionFile.create(new, Session.from_measurements(meas, left_hand()))
    os.utime(old, (1e9, 1e9))
    (tmp_path / ".new.json.abcdefgh.tmp").write_text("{")  # a write in progress: not listed
    (tmp_path / "broken.json").write_text('{"schema_version": 2, "poses": [')
    os.utime(tmp_path / "broken.json", (2e9, 2e9))
    entries = list_sessions(tmp_path)
    assert [e.path.name for e in entries] == ["broken.json", "new.json", "old.json"]
    broken, full, empty = entries
    assert broken.problem and "unreadable" in broken.row()[2]
    assert (full.robot, full.poses) == (left_hand().name, len(meas))
    assert full.last_step == str(meas.step[-1])
    assert (empty.poses, empty.last_step) == (0, "")
    assert (tmp_path / "broken.json").read_text() == '{"schema_version": 2, "poses": ['


def test_an_absent_directory_has_no_sessions(tmp_path):
    assert list_sessions(tmp_path / "nowhere") == []


def test_an_imported_session_is_listed_with_its_pose_blocks_poses(tmp_path):
    """The pose block beside it is not a session, and its poses are counted (from the file's
    own count: the list reads no block)."""
    from hexcal.procedure.session import import_table

    example = Path(__file__).parents[1] / "examples/left-hand-sim"
    import_table(example / "measurements.csv", left_hand(), tmp_path / "imported.json")
    [entry] = list_sessions(tmp_path)
    assert entry.path.name == "imported.json" and entry.poses == 184 and not entry.problem
