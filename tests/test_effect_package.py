"""The example effect package (examples/hexcal-scalebow) pip-installs, passes its own tests, and
its effect goes everywhere a catalogue effect goes: the simulator hides it, ``hexcal diagnose``
names it, ``--add`` brings the held-out RMS to the floor, ``calibrate --out`` records it with the
package and version, and ``predict`` and ``validate`` read it back — while a process without the
package refuses that model, naming the package to install.

The package is installed with pip into a folder of its own (``pip install --target``, offline),
and the ``hexcal`` runs that should see it get that folder on their ``PYTHONPATH``: hexcal finds
its entry point as it would in a site-packages, and the test environment of every other test is
left as it was.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from statcheck import floor_limit_of

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "examples" / "hexcal-scalebow"


def _pip_install(src: Path, target: Path) -> None:
    import setuptools

    major, minor = (int(x) for x in setuptools.__version__.split(".")[:2])
    assert (major, minor) >= (70, 1), (
        f"setuptools {setuptools.__version__} cannot build the example package offline: "
        "reinstall the test extras (pip install -e '.[test]')"
    )
    cmd = [sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation"]
    cmd += ["--no-index", "--target", str(target), str(src)]
    out = subprocess.run(cmd, capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The folder the package is pip-installed into (built from a copy: the repository's tree
    gets no build output)."""
    tmp = tmp_path_factory.mktemp("plugin")
    src = tmp / "hexcal-scalebow"
    shutil.copytree(PACKAGE, src, ignore=shutil.ignore_patterns("build", "*.egg-info"))
    _pip_install(src, tmp / "site")
    return tmp / "site"


def hexcal(*args: str | Path, site: Path | None = None, ok: bool = True):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    if site is not None:
        env["PYTHONPATH"] = str(site)
    out = subprocess.run(
        [sys.executable, "-m", "hexcal.app.cli", *map(str, args)],
        capture_output=True,
        text=True,
        env=env,
    )
    if ok:
        assert out.returncode == 0, out.stderr
    return out


@pytest.fixture(scope="module")
def session(site, tmp_path_factory):
    """A simulated session hiding scalebow (5–15 µm at 50 mm from home on each leg)."""
    out = tmp_path_factory.mktemp("bowed")
    hexcal("simulate", "--out", out, "--seed", "3", "--effect", "scalebow", site=site)
    return out


def inputs(d: Path) -> list[Path | str]:
    return [
        d / "measurements.csv",
        "--robot",
        d / "robot.json",
        "--instruments",
        d / "instruments.json",
    ]


@pytest.fixture(scope="module")
def calibrated(site, session, tmp_path_factory):
    path = tmp_path_factory.mktemp("cal") / "calibrated.json"
    hexcal("calibrate", *inputs(session), "--add", "scalebow", "--out", path, "--json", site=site)
    return path


def test_the_package_passes_its_own_tests(site):
    env = {**os.environ, "PYTHONPATH": str(site)}
    out = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(PACKAGE / "tests")],
        capture_output=True,
        text=True,
        env=env,
        cwd=site.parent,
    )
    assert out.returncode == 0, out.stdout + out.stderr
    assert "5 passed" in out.stdout


def test_calibrate_records_the_package_and_a_process_without_it_refuses_the_model(
    site, session, calibrated
):
    block = json.loads(calibrated.read_text())["calibration"]
    assert block["format_version"] == 3
    (rec,) = block["effects"]
    assert rec["name"] == "scalebow"
    assert rec["source"] == {
        "kind": "package",
        "package": "hexcal-scalebow",
        "version": "0.1.0",
        "entry_point": "scalebow = hexcal_scalebow:ScaleBow",
    }
    for command in ("validate", "predict"):
        out = hexcal(command, calibrated, session / "measurements.csv", ok=False)
        assert out.returncode == 2
        assert (
            "the effect comes from package hexcal-scalebow 0.1.0, which is not loaded" in out.stderr
        )
        assert "pip install 'hexcal-scalebow==0.1.0'" in out.stderr


@pytest.mark.slow
def test_diagnose_names_it_and_adding_it_reaches_the_floor(site, session):
    d = json.loads(hexcal("diagnose", *inputs(session), "--json", site=site).stdout)
    assert d["verdict"] == "scalebow"
    (c,) = [c for c in d["candidates"] if c["effect"] == "scalebow"]
    assert c["source"] == "package hexcal-scalebow 0.1.0" and c["identifiable"]
    after = json.loads(
        hexcal("diagnose", *inputs(session), "--add", "scalebow", "--json", site=site).stdout
    )
    assert after["verdict"] == "none"
    assert after["cv_rms_mm"] <= floor_limit_of(after)
    # Without the package the same session is "unexplained": the effect is what the data need.
    plain = json.loads(hexcal("diagnose", *inputs(session), "--json").stdout)
    assert plain["verdict"] == "unexplained"


def _column_block(path: Path, names: list[str]) -> np.ndarray:
    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    return np.array([[float(r[n]) for n in names] for r in rows])


@pytest.mark.slow
def test_predict_and_validate_read_it_back(site, session, calibrated, tmp_path):
    rho = [f"rho{k}" for k in range(1, 7)]
    poses, back = tmp_path / "poses.csv", tmp_path / "back.csv"
    table = session / "measurements.csv"
    hexcal("predict", calibrated, table, "--to", "pose", "--out", poses, site=site)
    hexcal("predict", calibrated, poses, "--to", "readings", "--out", back, site=site)
    assert np.abs(_column_block(back, rho) - _column_block(table, rho)).max() < 1e-6
    # The poses it computes from the readings are the tracker's, to the noise (floor 18.5 µm).
    pose = _column_block(poses, ["x", "y", "z"])
    assert np.sqrt(np.mean(np.sum((pose - _column_block(table, ["x", "y", "z"])) ** 2, 1))) < 0.03

    # On the session it was fitted on, validate reads the model but says it is no validation.
    v = json.loads(hexcal("validate", calibrated, table, "--json", site=site).stdout)
    assert v["own_session"] and v["verdict"] is None
    second = tmp_path / "second"
    hexcal(
        "simulate",
        "--out",
        second,
        "--seed",
        "3",
        "--pose-seed",
        "9",
        "--effect",
        "scalebow",
        site=site,
    )
    v2 = json.loads(
        hexcal(
            "validate",
            calibrated,
            second / "measurements.csv",
            "--instruments",
            second / "instruments.json",
            "--json",
            site=site,
        ).stdout
    )
    assert v2["verdict"] == "none"
