"""The operator's text UI, driven by Textual's Pilot: a whole guided session on the mock rig
through the real drivers, snapshots of the main screens, and resuming a killed session."""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from scipy import stats
from statcheck import pose_floor_limit

from hexcal.app.demo import DemoSettings, against_truth, run_demo
from hexcal.estimate.model_file import load_model, load_robot, save_model
from hexcal.io.measurements_csv import read_measurements
from hexcal.procedure.session import Session, load_session
from hexcal.sim.robots import left_hand
from hexcal.tui.app import HexcalApp
from hexcal.tui.backend import InstantBackend, mock_backend
from hexcal.tui.keys import KeyBar
from hexcal.tui.record import RecordScreen
from hexcal.tui.results import PLOT_MIN_ROWS, DiagnosisScreen, ResultScreen

SIZE = (130, 42)


async def _settle(pilot) -> None:
    """Until the workers are done and their results shown: a worker's result reaches the screen
    as a message after the worker ends, so on a loaded machine the screen can still be busy
    (and refuse the next key) when the workers are."""
    await pilot.pause()
    await pilot.app.workers.wait_for_complete()
    await _until(pilot, lambda: not getattr(pilot.app.screen, "busy", False), 10)
    await pilot.pause()


async def _until(pilot, cond, timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < end, "timed out"
        await pilot.pause(0.1)


async def _record_by_hand(pilot, g, tries: int = 5) -> None:
    """Press ``r`` until the pose is recorded, as an operator does after a refusal (the
    simulated devices share this process's threads, so a loaded machine can flag a reading)."""
    n = g.n_poses
    for _ in range(tries):
        aside = len(g.sf.session.set_aside)
        await pilot.press("r")
        # Wait for the outcome, not for the screen to look idle: with the pilot's idle wait cut
        # (quick_pilot) the key may not be handled yet when press returns.
        await _until(
            pilot,
            lambda aside=aside: (
                (g.n_poses > n or len(g.sf.session.set_aside) > aside) and not pilot.app.screen.busy
            ),
            10,
        )
        if g.n_poses > n:
            return
    raise AssertionError(
        f"{tries} presses of r recorded nothing: {g.sf.session.set_aside[-1].reason}"
    )


def instant_app(path: Path, poses_per_step: int = 4, **kw) -> HexcalApp:
    backend = InstantBackend(left_hand(), "instant mock rig", simulated=True, seed=2, effect="gain")
    return HexcalApp(backend, session_path=path, poses_per_step=poses_per_step, free_poses=12, **kw)


# -- the whole guided session, through the drivers -------------------------------------------------
@pytest.mark.slow
def test_a_whole_guided_session_on_the_mock_rig(tmp_path, quick_pilot):
    """Start a session, clamp and record every leg's steps and the free poses through the mock
    rig's drivers, calibrate, diagnose, add the named effect, export: the result matches the
    simulator's truth within its uncertainty, the diagnosis names the hidden effect, adding it
    lowers the error, and the export re-imports identically."""
    path = tmp_path / "session.json"
    app = HexcalApp(
        mock_backend(seed=5, effect="gain", window_s=0.25),
        session_path=path,
        poses_per_step=5,
        free_poses=15,
    )

    async def run() -> tuple[list, object]:
        async with app.run_test(size=SIZE) as pilot:
            await pilot.click("#new")
            await _until(pilot, lambda: isinstance(app.screen, RecordScreen), 30)
            g = app.guided
            # The first steps by hand, as an operator would: record home, next, clamp, move...
            await _record_by_hand(pilot, g)
            assert g.n_poses == 1
            await pilot.press("n")
            await pilot.press("c")
            await _until(pilot, lambda: g.clamped, 10)
            for i in range(5):
                await pilot.press("m")
                await _until(pilot, lambda: not app.screen.busy, 10)
                await _record_by_hand(pilot, g)
                assert g.n_poses == i + 1
            await pilot.press("n")
            # ...and the rest with the mock operator.
            await pilot.press("A")
            await _until(pilot, lambda: g.finished and not app.screen.busy, 300)
            assert [s[1] for s in g.summary()] == ["done"] * len(g.steps)
            await pilot.press("k")
            await _until(pilot, lambda: isinstance(app.screen, ResultScreen), 5)
            await _settle(pilot)
            await pilot.press("d")
            await _until(pilot, lambda: isinstance(app.screen, DiagnosisScreen), 5)
            screen = app.screen
            await _until(pilot, lambda: len(screen.history) == 1, 60)
            await pilot.press("a")
            await _until(pilot, lambda: len(screen.history) == 2, 60)
            await pilot.press("e")
            await pilot.pause()
            return screen.history, app.rig

    history, rig = asyncio.run(run())
    base, added = history
    assert base.verdict == "gain" == rig.hidden["name"]
    assert added.fit.cv_rms_mm < 0.5 * base.fit.cv_rms_mm
    assert added.verdict == "none"
    d2 = against_truth(added.fit.refinement, rig.truth)["mahalanobis2"]
    assert d2 < stats.chi2.ppf(0.999, 42), d2
    session = load_session(path)
    assert [r.kind for r in session.results] == ["calibration", "diagnosis", "diagnosis"]
    exported = read_measurements(tmp_path / "session-export" / "measurements.csv")
    assert exported == session.measurements()
    again = Session.from_measurements(exported, session.robot)
    assert again.measurements() == session.measurements()
    # The robot files re-import to what the session holds: the design, and the model of the
    # last step — the refit with the effect added, its geometry and its gains.
    assert load_robot(tmp_path / "session-export" / "robot.json") == session.robot
    shipped = load_model(tmp_path / "session-export" / "calibrated.json")
    refit = session.results[-1]
    assert shipped == refit.calibrated and refit.effects == ["gain"]
    assert shipped.calibration.model == "Model 42 + gain"
    geometry = load_robot(tmp_path / "session-export" / "calibrated.json")
    assert geometry == refit.robot.model_copy(update={"name": geometry.name})
    gains = np.array([p.value for p in shipped.calibration.effects[0].parameters])
    fitted = np.array([added.fit.refinement.value(f"gain.g{k}") for k in range(1, 7)])
    sigma = np.array([p.sigma for p in shipped.calibration.effects[0].parameters])
    assert np.all(np.abs(gains - fitted) < 3 * sigma)  # the clamp-aware refit of the same model
    _validate_on_a_second_session(
        tmp_path,
        shipped_path=tmp_path / "session-export" / "calibrated.json",
        uncorrected=session.results[0].calibrated,
    )


def _validate_on_a_second_session(tmp_path, shipped_path, uncorrected) -> None:
    """A second session of the same mock robot (same truth and hidden gain, the rig's noise
    and motion drawn anew), recorded headless through the same drivers and workflow: the
    exported model's pose error is at the noise floor there (within 3σ, σ from the pose count:
    tests/statcheck.py), the uncorrected model's is not."""
    second = tmp_path / "second.json"
    run_demo(
        DemoSettings(
            seed=5, effect="gain", rig_seed=55, poses_per_step=5, free_poses=15, session_path=second
        )
    )
    plain = tmp_path / "model42.json"
    save_model(uncorrected, plain)

    def validate(model_path) -> dict:
        out = subprocess.run(
            [
                sys.executable,
                "-m",
                "hexcal.app.cli",
                "validate",
                str(model_path),
                str(second),
                "--json",
            ],
            capture_output=True,
            text=True,
            check=True,
        )
        return json.loads(out.stdout)

    good, bad = validate(shipped_path), validate(plain)
    assert good["verdict"] == "none", good
    # Model 42 + gain: 48 parameters fitted on the first session
    limit = pose_floor_limit(good["position_floor_mm"], good["poses"], 48)
    assert good["position_rms_mm"] < limit, good
    assert bad["verdict"] != "none" and bad["position_rms_mm"] > 1.5 * bad["position_floor_mm"], bad


def test_the_operator_keeps_a_note_and_types_the_temperature(tmp_path):
    """o: a note, kept in the file with the time; t: the structure temperature (this rig has no
    thermometer), carried by every pose recorded after it; a wrong entry is refused, named."""
    path = tmp_path / "session.json"
    app = instant_app(path)

    async def run() -> None:
        async with app.run_test(size=SIZE) as pilot:
            await pilot.click("#new")
            await _settle(pilot)
            await pilot.press("o")
            await pilot.press(*"leg 2 clamp swapped", "enter")
            await pilot.press("t")
            await pilot.press(*"hot", "enter")
            await pilot.press("t")
            await pilot.press(*"22.5", "enter")
            await pilot.press("r")
            await _settle(pilot)
            text = "\n".join(str(line) for line in app.screen.query_one("#log").lines)
            assert "'hot' is not a temperature" in text and "note kept" in text
            assert "22.5 °C (entered)" in str(app.screen.query_one("#live").render())

    asyncio.run(run())
    on_disk = load_session(path)
    assert [n.text for n in on_disk.notes] == [
        "leg 2 clamp swapped",
        "structure temperature 22.5 °C (entered by the operator)",
    ]
    assert [r.temperature for r in on_disk.poses] == [22.5]
    assert on_disk.measurements().temperature.tolist() == [22.5]


# -- snapshots of the main screens -----------------------------------------------------------------
@pytest.fixture
def in_tmp(tmp_path, monkeypatch):
    """Run in an empty directory so the screens show the same relative session path."""
    monkeypatch.chdir(tmp_path)
    return tmp_path


#: The sizes the UI fits: the smallest terminal it supports, a common one, a large one.
SMALL, MEDIUM, LARGE = (80, 24), (120, 40), (200, 60)


def _text(widget) -> str:
    return str(widget.render())


def _assert_fits(pilot) -> None:
    """Every key the state allows is in the key bar, no row of live numbers is cut, and the
    diagnosis chart is seen whole where the summary leaves it room."""
    screen = pilot.app.screen
    bar = _text(screen.query_one(KeyBar))
    allowed = [k for k in screen.query_one(KeyBar).keys() if k.allowed]
    assert allowed and all(f"{k.shown} {k.description}" in bar for k in allowed), bar
    if isinstance(screen, RecordScreen):
        live = screen.query_one("#live")
        rows = [line for line in _text(live).split("\n") if line.startswith(("pos", "rot", "legs"))]
        numbers = [r for r in rows if not r.startswith("legs  ")]  # the bus status line is cut
        assert len(numbers) == 4 and all(len(r) <= live.content_size.width for r in numbers), rows
    if isinstance(screen, DiagnosisScreen):
        view = screen.query_one("#diag-scroll").scrollable_content_region
        # The chart whole, leg labels included (not under a scrollbar), wherever the summary
        # leaves it its least rows.
        summary = screen.query_one("#diag-summary").outer_size.height
        if summary + PLOT_MIN_ROWS <= view.height:
            plot = screen.query_one("#diag-plot").region
            assert view.contains_region(plot), (view, plot)


@pytest.mark.parametrize("size", [SMALL, MEDIUM], ids=lambda s: f"{s[0]}x{s[1]}")
def test_snapshot_start(snap_compare, in_tmp, size):
    """The start screen with three sessions listed and a session path longer than its field:
    the field shows the file's name and says its start is hidden; the list's title says how
    to reach it when it is below the fold."""
    from test_tui_session_lock import _session

    async def fits(pilot) -> None:
        _assert_fits(pilot)

    sessions = Path("sessions")
    sessions.mkdir()
    for k, stamp in enumerate(("20261127-101010", "20261128-064859", "20261128-070000")):
        _session(sessions / f"hexcal-session-{stamp}.json")
        when = 1_795_000_000 + 3600 * k  # fixed "changed" times: the snapshot must not move
        os.utime(sessions / f"hexcal-session-{stamp}.json", (when, when))
    path = Path("a lab's sessions", "platform 2", "hexcal-session-20261128-064859.json")
    app = instant_app(path, sessions=sessions)
    assert snap_compare(app, terminal_size=size, run_before=fits)


async def _record_some(pilot) -> None:
    await pilot.click("#new")
    await _settle(pilot)
    await _record_and_wait(pilot)
    await pilot.press("n", "c")
    for _ in range(5):
        await pilot.press("m")
        await _record_and_wait(pilot)
    _assert_fits(pilot)


async def _record_and_wait(pilot) -> None:
    """``r``, and the pose is in."""
    g = pilot.app.guided
    n = len(g.sf.session.poses)
    await pilot.press("r")
    await _settle(pilot)
    assert len(g.sf.session.poses) == n + 1, g.sf.session.set_aside[-1:]


@pytest.mark.parametrize("size", [SMALL, MEDIUM, LARGE], ids=lambda s: f"{s[0]}x{s[1]}")
def test_snapshot_recording(snap_compare, in_tmp, size):
    """Five poses into a step of eight: the next best pose is suggested; every key the state
    allows is shown, and the live numbers stand in whole columns."""
    assert snap_compare(
        instant_app(Path("session.json"), poses_per_step=8),
        terminal_size=size,
        run_before=_record_some,
    )


async def _record_all(pilot) -> None:
    await pilot.click("#new")
    await _settle(pilot)
    await pilot.press("A")
    await _until(pilot, lambda: pilot.app.guided.finished and not pilot.app.screen.busy, 60)
    await pilot.press("k")
    await _settle(pilot)
    _assert_fits(pilot)


def test_snapshot_result(snap_compare, in_tmp):
    assert snap_compare(
        instant_app(Path("session.json")), terminal_size=SMALL, run_before=_record_all
    )


async def _diagnose_and_add(pilot) -> None:
    await _record_all(pilot)
    await pilot.press("d")
    await _settle(pilot)
    await pilot.press("a")
    await _settle(pilot)
    assert pilot.app.screen.history[-1].verdict == "none"
    await pilot.press("a")  # nothing left to add: it says so
    assert "there is no effect to add" in _text(pilot.app.screen.query_one("#status"))
    _assert_fits(pilot)


@pytest.mark.parametrize("size", [SMALL, MEDIUM])
def test_the_diagnosis_chart_compares_the_models_where_it_has_the_rows(tmp_path, size):
    """The chart of held-out RMS per leg shows every model of the chain, named in its legend,
    where it has rows for bars below the legend; at 80×24, without the rows for a legend, it
    shows the fall: the first model and the last, each leg's pair of bars, named in its title
    (it showed the latest model alone)."""

    async def run() -> None:
        app = instant_app(tmp_path / "session.json")
        async with app.run_test(size=size) as pilot:
            await _diagnose_and_add(pilot)
            chart = pilot.app.screen.query_one("#diag-plot").plt.build()
            assert "Model 42 + gain" in chart
            assert "Model 42 " in chart.replace("Model 42 +", ""), chart  # the model before
            if size == SMALL:
                assert "Model 42 (left) → Model 42 + gain (right)" in chart, chart

    asyncio.run(run())


@pytest.mark.parametrize("size", [SMALL, MEDIUM], ids=lambda s: f"{s[0]}x{s[1]}")
def test_snapshot_diagnosis(snap_compare, in_tmp, size):
    """After adding the named effect: at 80×24 the chart shows the fall as each leg's pair of
    bars (before, after), at 120×40 every model with its legend."""
    assert snap_compare(
        instant_app(Path("session.json")), terminal_size=size, run_before=_diagnose_and_add
    )


def test_a_calibration_and_a_diagnosis_under_way_show_a_bar_what_and_how_long(
    tmp_path, monkeypatch
):
    """While the result and diagnosis screens' workers compute, a running progress bar says
    what is being done and for how long; it is gone once the result is shown. (The workers
    are held until the test has looked.)"""
    import threading

    import hexcal.app.workflow as workflow
    from hexcal.tui.working import Working

    gate = threading.Event()
    for name in ("calibrate_model", "diagnose_chain"):
        inner = getattr(workflow, name)

        def held(*args, _inner=inner, **kwargs):
            assert gate.wait(30)
            return _inner(*args, **kwargs)

        monkeypatch.setattr(workflow, name, held)
    app = instant_app(tmp_path / "session.json")

    async def look(pilot, screen_type, said: str) -> None:
        await _until(pilot, lambda: isinstance(app.screen, screen_type), 10)
        working = app.screen.query_one(Working)
        await pilot.pause(0.6)
        text = _text(working.query_one("#working-text"))
        assert working.display and re.match(rf" *\d+ s  {said}", text), text
        gate.set()
        await _until(pilot, lambda: not working.display, 60)
        gate.clear()

    async def run() -> None:
        async with app.run_test(size=SMALL) as pilot:
            await pilot.click("#new")
            await _settle(pilot)
            await pilot.press("A")
            await _until(pilot, lambda: app.guided.finished and not app.screen.busy, 60)
            await pilot.press("k")
            await look(pilot, ResultScreen, "calibrating Model 42")
            await _settle(pilot)
            await pilot.press("d")
            await look(pilot, DiagnosisScreen, "diagnosing Model 42")

    asyncio.run(run())


def test_every_key_the_state_refuses_says_why(tmp_path):
    """At 80×24, every key pressed when its action cannot run says why in the status line
    (and what to press instead); every action that changes the session leaves a log line; a
    step ended below its recommended count says so."""
    app = instant_app(tmp_path / "session.json", poses_per_step=8)

    async def run() -> None:
        async with app.run_test(size=SMALL) as pilot:

            async def refused(key: str, why: str) -> None:
                await pilot.press(key)
                await pilot.pause()
                text = _text(app.screen.query_one("#status"))
                assert why in text, (key, text)

            await refused("ctrl+r", "no such session file")
            await pilot.click("#new")
            await _until(pilot, lambda: isinstance(app.screen, RecordScreen), 10)
            await _settle(pilot)
            screen = app.screen
            log = screen.query_one("#log")
            await refused("c", "home clamps no leg: move the platform and record (r)")
            await refused("n", "home needs at least 1 pose (0 so far): record one more (r)")
            await refused("u", "home has no pose to undo")
            await refused("g", "home clamps no leg: no next best pose")
            await pilot.press("m", "r")
            await _settle(pilot)
            await pilot.press("n")
            await refused("r", "clamp leg 1 (direction+length) before recording (c)")
            await refused("m", "clamp leg 1 (direction+length) first (c)")
            await refused("g", "clamp leg 1 (direction+length) first (c)")
            await refused("n", "needs at least 4 poses (0 so far): record 4 more (r)")
            await pilot.press("c")
            for _ in range(3):
                await pilot.press("m", "r")
                await _settle(pilot)
            await refused("n", "needs at least 4 poses (3 so far): record one more (r)")
            await refused("g", "the next best pose needs 4 poses of this step (3 so far) (r)")
            await refused("c", "leg 1 is already clamped (direction+length)")
            screen.guided.thermometer = lambda: 21.0
            await refused("t", "this rig reads its own thermometer")
            screen.guided.thermometer = None
            await pilot.press("m", "r")
            await _settle(pilot)
            await pilot.press("g")
            await pilot.press("n")
            await _settle(pilot)
            lines = " ".join(line.text.strip() for line in log.lines)
            for said in (
                "moved home",
                "moved to the next pose",
                "leg 1 clamped (direction+length)",
                "moved to the suggested pose",
                "ended at 4 of 8 recommended poses (minimum 4)",
            ):
                assert said in lines, said
            while not screen.guided.finished:
                screen.guided.skip_step()
            screen.show_step()
            await refused("r", "the procedure is finished: every step is done or skipped (k)")
            await refused("a", "the procedure is finished")

    asyncio.run(run())


# -- a kill while recording ----------------------------------------------------------------------
RECORDER = textwrap.dedent(
    """
    import asyncio, sys
    sys.path.insert(0, {tests!r})
    from test_tui import instant_app
    from pathlib import Path

    async def main():
        app = instant_app(Path(sys.argv[1]))
        app.free_poses = 10000  # records until killed (a step's cap: hexcal.io.capacity)
        async with app.run_test(size=(130, 42)) as pilot:
            await pilot.click("#new")
            await pilot.app.workers.wait_for_complete()
            await pilot.pause()
            await pilot.press("A")
            print("recording", flush=True)
            while True:
                await pilot.pause(0.05)

    asyncio.run(main())
    """
)


@pytest.mark.parametrize("delay_s", [0.4, 1.7])
def test_a_killed_ui_leaves_a_session_that_resumes_where_it_stopped(tmp_path, delay_s):
    path = tmp_path / "killed.json"
    code = RECORDER.format(tests=str(Path(__file__).parent))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    proc = subprocess.Popen(
        [sys.executable, "-c", code, str(path)], stdout=subprocess.PIPE, env=env, cwd=tmp_path
    )
    assert proc.stdout.readline().strip() == b"recording"
    time.sleep(delay_s)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    saved = load_session(path)  # whole: a kill never leaves a damaged file
    n = len(saved.poses)
    assert n >= 1 and [p.pose_id for p in saved.poses] == list(range(1, n + 1))
    done = {p.step for p in saved.progress}

    app = instant_app(path)

    async def resume() -> tuple[str, int, int]:
        async with app.run_test(size=SIZE) as pilot:
            await pilot.click("#resume")
            await _until(pilot, lambda: isinstance(app.screen, RecordScreen), 10)
            g = app.guided
            before = g.n_poses
            await pilot.press("m" if g.step.leg == 0 or g.clamped else "c")
            if g.step.leg and not g.clamped:
                await pilot.press("m")
            await pilot.press("r")
            await _settle(pilot)
            return g.step.name, before, g.n_poses

    step, before, after = asyncio.run(resume())
    first_open = next(s for s in app.guided.steps if s.name not in done)
    assert step == first_open.name
    had = sum(1 for p in saved.poses if p.step == step)
    # The instant rig restarts unclamped: a partly recorded clamped step starts again, its
    # poses set aside (kept); a free step goes on.
    restarted = had if first_open.leg else 0
    assert before == had - restarted and after == before + 1
    now = load_session(path)
    assert len(now.poses) == n - restarted + 1
    assert len(now.set_aside) == len(saved.set_aside) + restarted
    assert np.all(np.isfinite(now.measurements().readings))


def test_device_warnings_wait_for_the_recording_log_and_never_cover_a_screen(tmp_path):
    """A driver's warning that comes while another screen shows is said in one status line and
    kept for the recording log; no notification is drawn over the screen."""
    import logging

    app = instant_app(tmp_path / "session.json")

    async def run() -> None:
        async with app.run_test(size=SMALL) as pilot:
            logging.getLogger("hexcal.drivers.test").warning("leg 4 encoder silent for 2 s")
            await pilot.pause()
            assert not app._notifications
            assert "device: leg 4 encoder silent" in _text(app.screen.query_one("#status"))
            await pilot.click("#new")
            await _settle(pilot)
            log = "\n".join(str(line) for line in app.screen.query_one("#log").lines)
            assert "leg 4 encoder silent for 2 s" in log

    asyncio.run(run())


def test_the_start_screen_lists_the_sessions_and_resumes_one_with_a_key(tmp_path):
    """A new session goes into the sessions directory (not the current folder); the next start
    lists it with its robot, poses and last step; ctrl+l, Enter resumes it."""
    sessions = tmp_path / "sessions"
    first = HexcalApp(
        InstantBackend(left_hand(), "instant mock rig", simulated=True, seed=2, effect="gain"),
        sessions=sessions,
        poses_per_step=4,
        free_poses=12,
    )

    async def record_one() -> None:
        async with first.run_test(size=SMALL) as pilot:
            await refused_without_sessions(pilot)
            await pilot.click("#new")
            await _until(pilot, lambda: isinstance(first.screen, RecordScreen), 10)
            await _settle(pilot)
            await pilot.press("m", "r")
            await _settle(pilot)

    async def refused_without_sessions(pilot) -> None:
        await pilot.press("ctrl+l")
        await pilot.pause()
        assert "no session in" in _text(pilot.app.screen.query_one("#status"))

    asyncio.run(record_one())
    [path] = sessions.glob("hexcal-session-*.json")
    assert load_session(path).poses

    again = instant_app(tmp_path / "unused.json", sessions=sessions)

    async def resume() -> None:
        async with again.run_test(size=SMALL) as pilot:
            table = again.screen.query_one("#sessions")
            row = [str(c) for c in table.get_row_at(0)]
            assert row[0] == path.name and row[1] == "1" and row[2] == "home"
            await pilot.press("ctrl+l", "enter")
            await _until(pilot, lambda: isinstance(again.screen, RecordScreen), 10)
            assert again.guided.sf.path == path and again.guided.n_poses == 1

    asyncio.run(resume())
    assert not (tmp_path / "unused.json").exists()


def test_the_diagnosis_screen_says_where_an_unexplained_residual_points(tmp_path, monkeypatch):
    """An unexplained verdict on the diagnosis screen names the covariate the residual
    follows, with its share of the excess and what it points at (the diagnosis is a simulated
    session's with joint play outside the catalogue, handed to the screen's worker); the key
    to add an effect adds the lead, written beside the session as an effect file. A stated
    noise too low is said with its factor."""
    from hexcal.app import workflow
    from hexcal.app.workflow import Inputs, diagnose_chain
    from hexcal.diagnosis import diagnose
    from hexcal.sim import verdict_cases as vc

    c = vc.foreign("joint play", 41)
    (play,) = diagnose_chain(Inputs(c.meas, c.design, c.instruments, "stated", "play"), 42)
    assert play.verdict == "unexplained" and play.exploration.lead is not None
    n = vc.noise_understated(41)
    noisy = diagnose(n.meas, n.design, 42, instruments=n.instruments)
    assert noisy.verdict == "noise_understated"
    shown = iter([play, noisy])
    monkeypatch.setattr(workflow, "diagnose_chain", lambda *a, **k: [next(shown)])
    app = instant_app(tmp_path / "session.json")

    async def run() -> None:
        async with app.run_test(size=SMALL) as pilot:
            await _record_all(pilot)
            await pilot.press("d")
            await _settle(pilot)
            summary = _text(app.screen.query_one("#diag-summary"))
            assert "it follows the axial leg force" in summary, summary
            assert "% of the excess" in summary
            assert "press a to add it as an effect" in " ".join(summary.split())
            await pilot.press("a")  # the lead, written and added; the next diagnosis shown
            await _settle(pilot)
            _assert_fits(pilot)
            summary = _text(app.screen.query_one("#diag-summary"))
            assert "the stated noise looks about 2.0× too low" in summary, summary

    from hexcal.effects import CATALOGUE

    before = set(CATALOGUE)
    try:
        asyncio.run(run())
    finally:  # the written file's effect is this test's, not the next one's
        for name in set(CATALOGUE) - before:
            CATALOGUE.pop(name, None)
    written = tmp_path / "session-effects" / "by_force.py"
    assert written.exists() and "class ByForce(ExploredEffect)" in written.read_text()
