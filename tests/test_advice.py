"""Advice that runs as printed (hexcal.io.advice): every command hexcal prints for its user to
run — "Find what:", "Next:", the examples' first command, the demo's next step — is collected
from the outputs of the commands the docs show, over the shipped examples and the docs'
sessions, then run as printed by a shell from where the user was. Each must exit 0, and write
over nothing that was there before it ran."""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from hexcal.io import advice

ROOT = Path(__file__).resolve().parents[1]
WALKTHROUGH = ROOT / "docs" / "walkthrough"
#: The ``hexcal`` of this interpreter's environment: the command as a user types it.
HEXCAL = Path(sys.executable).parent / "hexcal"
INPUTS = ["measurements.csv", "--robot", "robot.json", "--instruments", "instruments.json"]


def _run(cmd: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PATH=f"{HEXCAL.parent}{os.pathsep}{os.environ.get('PATH', '')}")
    env["COLUMNS"] = "100"
    return subprocess.run(
        ["bash", "-c", cmd], cwd=cwd, env=env, capture_output=True, text=True, timeout=600
    )


def advised(text: str) -> list[str]:
    """The commands ``text`` advises: its lines :data:`hexcal.io.advice.ADVICE_LINE` matches."""
    return [m.group(1) for t in text.splitlines() if (m := advice.ADVICE_LINE.match(t))]


def _files(folder: Path) -> dict[Path, tuple[int, int]]:
    return {p: (p.stat().st_mtime_ns, p.stat().st_size) for p in folder.rglob("*") if p.is_file()}


def _follow(args: list[str], cwd: Path, depth: int = 3) -> list[str]:
    """Run ``hexcal ARGS`` in ``cwd``, then every command it advises, as printed, from the same
    folder, and what those advise in turn (``depth`` levels): each must exit 0 and leave every
    file that was there untouched. The advised commands, in the order run, for the caller to
    check their words."""
    first = _run(shlex.join(["hexcal", *args]), cwd)
    assert first.returncode == 0, first.stderr
    return _advice_of(first.stdout + first.stderr, cwd, depth)


def _advice_of(text: str, cwd: Path, depth: int) -> list[str]:
    out = []
    for cmd in advised(text):
        for word in shlex.split(cmd):  # quoted as the shell reads it back: every word whole
            assert "\n" not in word
        before = _files(cwd)
        done = _run(cmd, cwd)
        assert done.returncode == 0, f"{cmd!r} exited {done.returncode}: {done.stderr[-2000:]}"
        after = _files(cwd)
        changed = [p for p, stamp in before.items() if after.get(p) != stamp]
        assert not changed, f"{cmd!r} wrote over {changed}"
        out.append(cmd)
        if depth > 1:
            out += _advice_of(done.stdout + done.stderr, cwd, depth - 1)
    return out


@pytest.fixture(scope="module")
def examples(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("advice") / "my examples"  # a space: the quoting is tested
    done = _run(shlex.join(["hexcal", "examples", "--out", str(out)]), out.parent)
    assert done.returncode == 0, done.stderr
    [cmd] = advised(done.stdout)
    assert cmd.startswith(f"cd {shlex.quote(str(out / 'left-hand-backlash'))} && hexcal diagnose")
    assert _run(cmd, out.parent).returncode == 0
    return out


def test_calibrates_advice_carries_the_users_inputs_and_runs(examples):
    """The issue's case: "Find what: hexcal diagnose measurements.csv --auto" exited 2 without
    the --robot the user had given, and dropped --instruments."""
    [cmd] = _follow(["calibrate", *INPUTS], examples / "left-hand-backlash")
    assert cmd == shlex.join(["hexcal", "diagnose", *INPUTS, "--auto"])


def test_diagnoses_next_step_adds_the_named_effect_to_the_users_own_command(examples):
    cwd = examples / "left-hand-backlash"
    cmd = _follow(["diagnose", *INPUTS, "--exclude-poses", "3", "5", "--add", "gain"], cwd)[0]
    assert cmd == shlex.join(
        ["hexcal", "diagnose", *INPUTS, "--exclude-poses", "3", "5", "--add", "gain", "backlash"]
    )
    # A clean session and a chain that ended at the floor advise nothing more.
    assert _follow(["diagnose", *INPUTS], examples / "left-hand-sim") == []
    assert _follow(["diagnose", *INPUTS, "--auto", "--report", "report.html"], cwd) == []


def test_the_jugglebots_advice_runs_on_its_drawing(examples):
    cwd = examples / "jugglebot"
    args = ["import", "108_calibration_poses.csv", "--map", "map.toml", "--out", "table.csv"]
    assert _run(shlex.join(["hexcal", *args]), cwd).returncode == 0
    for command in ("calibrate", "diagnose"):
        for cmd in _follow([command, "table.csv", "--robot", "design-robot.json"], cwd):
            assert "--robot design-robot.json" in cmd


@pytest.mark.parametrize("folder", ["session", "validation", "tests", "unexplained"])
def test_the_docs_sessions_advice_runs(tmp_path, folder):
    """The walkthrough's sessions, copied (the advice writes beside its input): calibrate's and
    diagnose's advice; an unexplained residual's is to write an effect file, named so that it
    writes over nothing, and the line that file's writing prints runs too."""
    cwd = tmp_path / folder
    shutil.copytree(WALKTHROUGH / folder, cwd)
    for command in ("calibrate", "diagnose"):
        commands = _follow([command, *INPUTS], cwd)
        if folder == "unexplained":
            # calibrate → diagnose --auto → write an effect file → diagnose with it; diagnose
            # → the same, its effect file named after the first, which is left as it was.
            name = (
                "measurements-effect.py" if command == "calibrate" else "measurements-effect-2.py"
            )
            write, edited = commands[-2:]
            assert write.endswith(f"--effect-file {name}"), commands
            assert f"--effects {name} --add " in edited, commands


@pytest.mark.slow
def test_a_second_demo_sessions_advice_writes_its_own_report(tmp_path):
    """The demo advises a report named after its session: the second session's advice does
    not write over the first session's report (it advised report.html for both)."""
    small = ["demo", "--seed", "7", "--effect", "backlash", "--poses-per-step", "3"]
    small += ["--free-poses", "10"]
    first = _follow([*small, "--session", "s1.json"], tmp_path)
    second = _follow([*small, "--rig-seed", "8", "--session", "s2.json"], tmp_path)
    assert [c.split("--report ")[1] for c in (*first, *second)] == [
        "s1-report.html",
        "s2-report.html",
    ]
    assert "--add backlash" in first[0] and (tmp_path / "s1-report.html").exists()


def test_free_path_never_names_a_file_that_is_there(tmp_path):
    (tmp_path / "s-report.html").write_text("first")
    (tmp_path / "s-report-2.html").write_text("second")
    assert advice.beside(tmp_path / "s.json", "report", ".html") == tmp_path / "s-report-3.html"
    assert advice.free_path(tmp_path / "new.html") == tmp_path / "new.html"
