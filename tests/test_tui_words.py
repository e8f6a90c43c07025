"""The text UI's words: each said once, counted right, and keys where keys are meant."""

from __future__ import annotations

import asyncio
from pathlib import Path

from test_tui import _until, instant_app
from test_tui_session_lock import _session

from hexcal.procedure.session import load_session
from hexcal.tui.record import RecordScreen


def _log_text(app) -> str:
    return "\n".join(line.text for line in app.screen.query_one("#log").lines)


def test_a_resumed_sessions_notice_is_logged_once_and_one_pose_is_one_pose(tmp_path: Path):
    """Resuming tidies an interrupted save's temporary file: the recording log says so once
    (it came twice: through the log handler and again from the session's notices), and a
    session of one pose says "1 pose"."""
    path = tmp_path / "s.json"
    _session(path)
    session = load_session(path)
    session.poses = session.poses[:1]
    path.write_text(session.model_dump_json())
    orphan = tmp_path / ".s.json.a1b2c3d4.tmp"
    orphan.write_text("{")
    app = instant_app(path)

    async def run() -> None:
        async with app.run_test(size=(130, 42)) as pilot:
            await pilot.click("#resume")
            await _until(pilot, lambda: isinstance(app.screen, RecordScreen), 20)
            await pilot.pause(0.3)
            log = " ".join(_log_text(app).split())
            assert log.count("a temporary file") == 1, log
            assert "1 pose so far" in log and "1 poses" not in log, log

    asyncio.run(run())
    assert not orphan.exists()


def test_the_result_screens_words_name_keys_not_command_lines():
    """What the result screen shows of a calibration that misses an effect says "press d", and
    the clamp check it quotes (shared with the command line) names no command or option: the
    UI's keys are d and a, not "run hexcal diagnose, then --add it"."""
    from hexcal.app.plain import calibration_summary
    from hexcal.app.workflow import calibrate_model, read_inputs

    d = Path(__file__).resolve().parents[1] / "examples" / "left-hand-backlash"
    inp = read_inputs(d / "measurements.csv", d / "robot.json", d / "instruments.json")
    result = calibrate_model(inp, 42)
    clamps = result.calibration.clamp_check
    assert clamps is not None and clamps.model_misfit
    assert "the diagnosis names it" in clamps.text
    assert "hexcal" not in clamps.text and "--" not in clamps.text, clamps.text
    plain = calibration_summary(result.name, result.accuracy, [], "press d to diagnose")
    assert plain[0].endswith("Find what: press d to diagnose"), plain


def test_at_80x24_the_log_shows_the_session_files_name_whole_and_rewraps_on_resize(tmp_path):
    """The log wrapped a path at a width 2 columns wider than it shows (the scroll bar's
    gutter), so "…-064859.json" read "…-06485" / "json"; and it kept its wrapping when the
    window grew. Every character is on screen now, at 80×24 and again at 120×40."""
    path = tmp_path / "hexcal-session-20261128-064859.json"
    app = instant_app(path)

    async def run() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.click("#new")
            await _until(pilot, lambda: isinstance(app.screen, RecordScreen), 20)
            await pilot.pause(0.3)
            log = app.screen.query_one("#log")
            widest = []
            for size in ((80, 24), (120, 40)):
                await pilot.resize_terminal(*size)
                await pilot.pause(0.3)
                shown = log.scrollable_content_region.width
                lines = [line.text.rstrip() for line in log.lines]
                assert all(len(line) <= shown for line in lines), (shown, lines)
                assert str(path) in "".join(lines), lines  # wrapped, nothing lost
                widest.append((shown, max(len(line) for line in lines)))
            (narrow, _), (wide, used) = widest
            assert used > narrow and wide > narrow, widest  # wrapped again, at the new width

    asyncio.run(run())


def test_the_diagnosis_screens_statistics_name_the_key_that_adds():
    """The statistics the diagnosis screen shows are the command line's, with the key where
    the command line says its option ("Add it: --add backlash" on a screen where it is a)."""
    from hexcal.app.workflow import diagnose_chain, read_inputs
    from hexcal.diagnosis.text import diagnosis_text

    d = Path(__file__).resolve().parents[1] / "examples" / "left-hand-backlash"
    inp = read_inputs(d / "measurements.csv", d / "robot.json", d / "instruments.json")
    (first,) = diagnose_chain(inp, 42)
    assert first.verdict == "backlash"
    assert "Add it: --add backlash" in diagnosis_text(first, "cli")
    screen = diagnosis_text(first, "session.json", add="key a")
    assert "Add it: key a" in screen and "--add" not in screen


def test_an_imported_tables_poses_are_counted_with_the_recorded_ones(tmp_path: Path):
    """A session whose table sits in its pose block (imported, then given a procedure) holds
    the table's poses: resuming says so, as the sessions list does (it counted 0: only the
    poses recorded in the session file were counted)."""
    from test_tui_session_lock import EXAMPLE

    from hexcal.estimate.model_file import load_robot
    from hexcal.io.measurements_csv import read_measurements
    from hexcal.procedure.session import Session, SessionFile
    from hexcal.procedure.sessions_dir import list_sessions
    from hexcal.procedure.steps import load_procedure

    path = tmp_path / "s.json"
    meas = read_measurements(EXAMPLE / "measurements.csv").subset(slice(0, 5))
    session = Session.with_table(meas, load_robot(EXAMPLE / "robot.json"))
    session.procedure = load_procedure("model42-direction-length").model_dump(by_alias=True)
    assert session.pose_count() == 5  # the table not written yet
    SessionFile.create(path, session).close()
    loaded = load_session(path)
    assert loaded.pose_block is not None and loaded.poses == []
    assert loaded.pose_count() == 5
    [entry] = list_sessions(tmp_path)
    assert entry.poses == 5
    app = instant_app(path)

    async def run() -> None:
        async with app.run_test(size=(130, 42)) as pilot:
            await pilot.click("#resume")
            await _until(pilot, lambda: isinstance(app.screen, RecordScreen), 20)
            await pilot.pause(0.3)
            log = " ".join(_log_text(app).split())
            assert "5 poses so far" in log, log
            assert app.screen.why_not("calibrate") is None

    asyncio.run(run())
