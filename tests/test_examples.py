"""The examples a newcomer learns from (examples/, installed as hexcal.examples): the Quick
start's session hides backlash and the diagnosis shows the error falling to the noise floor, the
clean one says `none`, and the Jugglebot's commands run from the folder `hexcal examples` writes
out of the installed package."""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from statcheck import floor_limit_of, pose_floor_limit

from hexcal.app.cli import main
from hexcal.app.commands.examples import example_files

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"


@pytest.fixture(scope="module")
def written(tmp_path_factory) -> Path:
    """The examples as `hexcal examples` writes them from the installed package."""
    out = tmp_path_factory.mktemp("ex") / "hexcal-examples"
    assert main(["examples", "--out", str(out)]) == 0
    return out


def _diagnose_auto(folder: Path, capsys) -> dict:
    capsys.readouterr()
    argv = ["diagnose", "measurements.csv", "--robot", "robot.json"]
    argv += ["--instruments", "instruments.json", "--auto", "--json"]
    cwd = Path.cwd()
    os.chdir(folder)
    try:
        assert main(argv) == 0
    finally:
        os.chdir(cwd)
    return json.loads(capsys.readouterr().out)


def test_the_quick_start_example_shows_the_error_falling_to_the_floor(written, capsys):
    """Model 42 leaves ≥ 2× the noise floor (leg lengths held out, and the pose error against its
    own floor); the diagnosis names backlash, --auto adds it, and both end at the floor: within
    3σ of a correct model's (σ for the leg lengths from the pose count, χ² one dof a pose, an
    upper bound; likewise for the pose error: tests/statcheck.py)."""
    out = _diagnose_auto(written / "left-hand-backlash", capsys)
    first, last = out["steps"][0], out["steps"][-1]
    assert (first["model"], first["verdict"]) == ("Model 42", "backlash")
    assert (last["model"], last["verdict"]) == ("Model 42 + backlash", "none")
    assert first["cv_rms_mm"] >= 2 * first["noise_floor_mm"]
    assert last["cv_rms_mm"] <= floor_limit_of(out)  # out: the last step's whole diagnosis
    pose = first["pose_accuracy"]
    assert pose["position_rms_mm"] >= 2 * pose["floor_position_rms_mm"], pose
    pose = last["pose_accuracy"]
    floor, poses = pose["floor_position_rms_mm"], pose["poses"]
    assert pose["position_rms_mm"] <= pose_floor_limit(floor, poses, len(out["parameters"])), pose
    # The simulator hid backlash on every leg; the fitted play is the true one within 3 σ.
    truth = json.loads((written / "left-hand-backlash" / "truth.json").read_text())
    true_play = truth["effect_values"]
    fitted = {p["name"]: p for p in out["parameters"] if p["name"].startswith("backlash.")}
    assert len(fitted) == 6
    for k in range(6):
        p = fitted[f"backlash.beta{k + 1}"]
        assert abs(p["value"] - true_play[p["name"]]) < 3 * p["sigma"], p


def test_the_clean_example_is_at_the_floor_at_once(written, capsys):
    out = _diagnose_auto(written / "left-hand-sim", capsys)
    # No step was added: the one diagnosis is the answer (no "steps" chain in the output).
    assert (out["model"], out["verdict"]) == ("Model 42", "none")
    assert "steps" not in out
    assert out["cv_rms_mm"] <= floor_limit_of(out)


def test_the_examples_are_the_simulators_output(tmp_path):
    """Each simulated example is exactly what the command examples/README.md names writes."""
    readme = (EXAMPLES / "README.md").read_text()
    commands = re.findall(r"`(hexcal simulate [^`]*)`", readme.replace("\n", " "))
    assert len(commands) == 2
    for command in commands:
        argv = shlex.split(command)[1:]
        folder = argv[argv.index("--out") + 1]
        argv[argv.index("--out") + 1] = str(tmp_path / folder)
        assert main(argv) == 0
        for name in ("robot.json", "measurements.csv", "instruments.json", "truth.json"):
            assert (tmp_path / folder / name).read_text() == (EXAMPLES / folder / name).read_text()


def test_the_installed_package_carries_every_example_file(written):
    """Everything under examples/ in the repository is in the package (the package-data globs
    miss nothing), and `hexcal examples` wrote it byte for byte."""
    tracked = sorted(
        p.relative_to(EXAMPLES).as_posix()
        for p in EXAMPLES.rglob("*")
        if p.is_file()
        and "__pycache__" not in p.parts
        and p != EXAMPLES / "__init__.py"  # the folder's own package file, not an example
    )
    assert sorted(example_files()) == tracked
    for name in tracked:
        assert (written / name).read_bytes() == (EXAMPLES / name).read_bytes(), name


def test_examples_refuses_to_overwrite_and_names_what(written, capsys):
    assert main(["examples", "--out", str(written)]) != 0
    err = capsys.readouterr().err
    n = len(example_files())
    assert f"already holds {n} of the examples' {n} files" in err and "--force" in err
    assert main(["examples", "--out", str(written / "README.md")]) != 0
    assert "is a file, not a directory" in capsys.readouterr().err


def _readme_commands(readme: Path) -> list[list[str]]:
    """The hexcal commands of a README's bash block, as argv lists (without "hexcal")."""
    block = re.search(r"```bash\n(.*?)```", readme.read_text(), re.S)
    assert block, readme
    lines = [ln for ln in block.group(1).splitlines() if ln.startswith("hexcal ")]
    return [shlex.split(ln)[1:] for ln in lines]


def test_the_jugglebot_commands_run_from_the_written_folder(written, capsys):
    """examples/jugglebot/README.md's commands, run inside the folder `hexcal examples` wrote:
    the import reads the log through its map, the diagnosis names the gains first."""
    commands = _readme_commands(written / "jugglebot" / "README.md")
    assert [c[0] for c in commands] == ["import", "diagnose"]
    cwd = Path.cwd()
    os.chdir(written / "jugglebot")
    try:
        capsys.readouterr()
        assert main(commands[0]) == 0
        assert "108 poses" in capsys.readouterr().out
        assert main([*commands[1], "--json"]) == 0
    finally:
        os.chdir(cwd)
    out = json.loads(capsys.readouterr().out)
    assert out["steps"][0]["verdict"] == "gain"
    assert out["poses_used"] == 108


@pytest.mark.slow
def test_the_jugglebot_command_works_from_a_built_wheel(tmp_path):
    """Not the editable install: a wheel built from the repository's files, unpacked alone on
    the path, writes the examples and runs the Jugglebot's import and a calibration there."""
    src = tmp_path / "src"
    files = subprocess.run(
        ["git", "ls-files", "-co", "--exclude-standard"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    for name in files:
        if (ROOT / name).is_file() and not name.startswith(("tests/", "benchmarks/", "docs/")):
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            (src / name).write_bytes((ROOT / name).read_bytes())
    wheels = tmp_path / "wheels"
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(wheels), str(src)],
        check=True,
    )
    site = tmp_path / "site"
    with zipfile.ZipFile(next(wheels.glob("hexcal-*.whl"))) as whl:
        whl.extractall(site)
    env = {**os.environ, "PYTHONPATH": str(site), "OPENBLAS_NUM_THREADS": "1"}
    work = tmp_path / "work"
    work.mkdir()

    def hexcal(*argv: str, cwd: Path) -> str:
        code = "import sys, hexcal; from hexcal.app.cli import main; "
        code += f"assert hexcal.__file__.startswith({str(site)!r}), hexcal.__file__; "
        code += "sys.exit(main(sys.argv[1:]))"
        done = subprocess.run(
            [sys.executable, "-c", code, *argv], cwd=cwd, env=env, capture_output=True, text=True
        )
        assert done.returncode == 0, done.stderr
        return done.stdout

    hexcal("examples", cwd=work)
    folder = work / "hexcal-examples" / "jugglebot"
    commands = _readme_commands(folder / "README.md")
    assert "108 poses" in hexcal(*commands[0], cwd=folder)
    out = hexcal("calibrate", "measurements.csv", "--robot", "design-robot.json", cwd=folder)
    assert "Model 42" in out
