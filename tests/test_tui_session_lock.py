"""Two text-UI windows on one session, started together on a barrier: one resumes it and
records, the other is refused on its start screen, told which process on which host holds the
session since when, and records nothing; once the first has closed, the session resumes with
every pose the first recorded."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from hexcal.estimate.model_file import load_robot
from hexcal.io.measurements_csv import read_measurements
from hexcal.procedure.session import Session, SessionFile, load_session
from hexcal.procedure.steps import load_procedure

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "left-hand-sim"

WINDOW = textwrap.dedent(
    """
    import asyncio, json, os, sys, time
    from pathlib import Path
    sys.path.insert(0, {tests!r})
    from test_tui import _text, _until, instant_app
    from hexcal.tui.record import RecordScreen

    async def main():
        path, go, me, other = (Path(a) for a in sys.argv[1:5])
        app = instant_app(path)
        async with app.run_test(size=(130, 42)) as pilot:
            print("ready", flush=True)
            while not go.exists():
                await asyncio.sleep(0.005)
            await pilot.click("#resume")
            status = ""
            end = time.monotonic() + 60
            while time.monotonic() < end and not isinstance(app.screen, RecordScreen):
                await pilot.pause(0.02)
                status = _text(app.screen.query_one("#status"))
                if "open for writing" in status:
                    break
            opened = isinstance(app.screen, RecordScreen)
            me.write_text(json.dumps({{"pid": os.getpid(), "opened": opened, "status": status}}))
            if opened:  # hold the session until the other window has tried, then record
                await _until(pilot, other.exists, 60)
                await pilot.app.workers.wait_for_complete()
                for _ in range(3):
                    n = app.guided.n_poses
                    await pilot.press("m")
                    await _until(pilot, lambda: not app.screen.busy, 20)
                    await pilot.press("r")
                    await _until(pilot, lambda: not app.screen.busy, 20)
                    assert app.guided.n_poses == n + 1
        print("closed", flush=True)

    asyncio.run(main())
    """
)


def _session(path: Path) -> None:
    meas = read_measurements(EXAMPLE / "measurements.csv").subset(slice(0, 3))
    proc = load_procedure("model42-direction-length")
    session = Session.from_measurements(meas, load_robot(EXAMPLE / "robot.json"))
    session.procedure = proc.model_dump(by_alias=True)
    SessionFile.create(path, session).close()


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX lock")
def test_two_ui_windows_on_one_session_one_records_the_other_is_told_who_holds_it(tmp_path):
    path = tmp_path / "shared.json"
    _session(path)
    before = len(load_session(path).poses)
    go = tmp_path / "go"
    said = {w: tmp_path / f"{w}.said" for w in "AB"}
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    code = WINDOW.format(tests=str(Path(__file__).parent))
    windows = {
        w: subprocess.Popen(
            [sys.executable, "-c", code, str(path), str(go), str(said[w]), str(said[o])],
            stdout=subprocess.PIPE,
            env=env,
            cwd=tmp_path,
        )
        for w, o in (("A", "B"), ("B", "A"))
    }
    try:
        for proc in windows.values():  # the barrier: both windows are up, then both resume
            assert proc.stdout is not None and proc.stdout.readline().strip() == b"ready"
        go.touch()
        for proc in windows.values():
            proc.wait(120)
    finally:
        for proc in windows.values():
            proc.kill()
    assert [p.returncode for p in windows.values()] == [0, 0]
    outcome = {w: json.loads(said[w].read_text()) for w in "AB"}
    holders = [w for w in "AB" if outcome[w]["opened"]]
    assert len(holders) == 1, outcome
    holder = holders[0]
    refused = "B" if holder == "A" else "A"
    status = outcome[refused]["status"]
    assert f"open for writing in process {outcome[holder]['pid']} " in status, status
    assert f"on host {socket.gethostname()} since " in status, status
    # The holder's poses are all there; the refused window recorded none; the lock is free.
    after = load_session(path)
    assert len(after.poses) == before + 3
    deadline = time.monotonic() + 5
    while True:
        try:
            SessionFile.resume(path).close()
            break
        except Exception:
            assert time.monotonic() < deadline
            time.sleep(0.1)
