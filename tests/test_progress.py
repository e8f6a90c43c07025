"""Progress of long jobs: drawn on a terminal, never with ``--json`` or into a pipe; stdout
stays the results' alone."""

from __future__ import annotations

import io
import os
import pty
import select
import subprocess
import sys
from pathlib import Path

import pytest

from hexcal.app.progress import progress, wanted

EXAMPLE = Path(__file__).parents[1] / "examples" / "left-hand-sim"
#: The example's measurements with its robot and instruments, as the commands take them.
EXAMPLE_INPUTS = [
    str(EXAMPLE / "measurements.csv"),
    "--robot",
    str(EXAMPLE / "robot.json"),
    "--instruments",
    str(EXAMPLE / "instruments.json"),
]


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_drawn_only_on_a_terminal_and_never_for_json():
    assert wanted(False, _Terminal())
    assert not wanted(True, _Terminal())
    assert not wanted(False, io.StringIO())


def test_stages_are_drawn_and_removed_when_the_job_ends():
    screen = _Terminal()
    with progress(True, screen) as bar:
        bar.stage("diagnosing Model 42")
        bar.stage("drawing the plots", total=3)
        bar.advance()
    assert "diagnosing Model 42" in screen.getvalue() or "drawing the plots" in screen.getvalue()
    with progress(False, screen) as quiet:
        quiet.stage("nothing")
        assert not quiet.shown


def _run_on_a_terminal(args: list[str], cwd: Path) -> tuple[str, str]:
    """Run ``hexcal args`` with stderr on a pseudo-terminal: (stdout, what the terminal got)."""
    master, slave = pty.openpty()
    # stdout to a file: a pipe read only at the end would block a child that prints more
    # than the pipe holds (calibrate --json).
    stdout = (cwd / "stdout.txt").open("w+", encoding="utf-8")
    proc = subprocess.Popen(
        [sys.executable, "-m", "hexcal.app.cli", *args],
        stdout=stdout,
        stderr=slave,
        cwd=cwd,
        text=True,
    )
    os.close(slave)
    screen = b""
    while True:
        ready, _, _ = select.select([master], [], [], 0.2)
        if ready:
            try:
                chunk = os.read(master, 65536)
            except OSError:  # the child closed the terminal
                break
            if not chunk:
                break
            screen += chunk
        elif proc.poll() is not None:
            break
    assert proc.wait(timeout=300) == 0, screen.decode(errors="replace")
    stdout.seek(0)
    out = stdout.read()
    stdout.close()
    os.close(master)
    return out, screen.decode(errors="replace")


@pytest.mark.slow
def test_diagnose_auto_report_shows_progress_on_a_terminal_and_none_with_json(tmp_path):
    inputs = ["diagnose", *EXAMPLE_INPUTS, "--auto"]
    out, screen = _run_on_a_terminal([*inputs, "--report", "r.html"], tmp_path)
    assert "diagnosing Model 42" in screen and "writing the report" in screen
    assert "diagnosing" not in out and "report written to r.html" in out
    out, screen = _run_on_a_terminal([*inputs, "--json"], tmp_path)
    assert screen == "" and out.lstrip().startswith("{")


def test_calibrate_shows_its_stages_on_a_terminal_and_none_with_json(tmp_path):
    """``hexcal calibrate`` (over a second on a few thousand poses) names each stage on the
    terminal; stdout keeps only the results, and ``--json`` draws nothing."""
    inputs = ["calibrate", *EXAMPLE_INPUTS]
    out, screen = _run_on_a_terminal(inputs, tmp_path)
    assert "calibrating Model 42 on" in screen and "pose accuracy on held-out poses" in screen
    assert "calibrating Model 42 on" not in out and "pose accuracy" in out
    out, screen = _run_on_a_terminal([*inputs, "--json"], tmp_path)
    assert screen == "" and out.lstrip().startswith("{")
