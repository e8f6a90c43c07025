"""The hexcal command line: calibrate (text, JSON, --out), simulate, errors on stderr."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hexcal.cli import EXIT_INPUT, EXIT_REFUSED, main
from hexcal.robot import load_robot

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "left-hand-sim"


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    out = tmp_path_factory.mktemp("sess")
    assert main(["simulate", "--out", str(out), "--seed", "5"]) == 0
    return out


def test_calibrate_json_has_the_contract(session, capsys):
    rc = main(
        [
            "calibrate",
            str(session / "measurements.csv"),
            "--robot",
            str(session / "robot.json"),
            "--model",
            "42",
            "--instruments",
            str(session / "instruments.json"),
            "--json",
        ]
    )
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    for key in ("model", "base_points", "platform_points", "leg_offsets", "rms_mm", "methods"):
        assert key in out
    assert out["model"] == 42
    assert np.shape(out["base_points"]) == (6, 3) and np.shape(out["platform_points"]) == (6, 3)
    assert len(out["leg_offsets"]) == 6 and len(out["methods"]) == 6
    truth = json.loads((session / "truth.json").read_text())
    err = np.abs(np.array(out["base_points"]) - truth["base_points"])
    assert np.all(err < 5 * np.array(out["base_points_ci95"]) / 1.96)
    assert 0.005 < out["rms_mm"] < 0.05


def test_calibrate_text_and_out(session, tmp_path, capsys):
    out_robot = tmp_path / "cal.json"
    rc = main(
        [
            "calibrate",
            str(session / "measurements.csv"),
            "--robot",
            str(session / "robot.json"),
            "--model",
            "36",
            "--out",
            str(out_robot),
        ]
    )
    assert rc == 0
    text = capsys.readouterr().out
    assert "method per leg" in text and "leg 3: §3.2" in text and "residual RMS" in text
    cal = load_robot(out_robot)
    assert cal.name.endswith("-calibrated") and cal.leadscrew_pitch_mm == 5.0


def test_bad_csv_exits_2_naming_file_line_column(session, tmp_path, capsys):
    lines = (session / "measurements.csv").read_text().splitlines()
    cells = lines[4].split(",")
    cells[8] = "abc"  # qw
    lines[4] = ",".join(cells)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n")
    rc = main(["calibrate", str(bad), "--robot", str(session / "robot.json")])
    err = capsys.readouterr().err
    assert rc == EXIT_INPUT
    assert "bad.csv" in err and "line 5" in err and "'qw'" in err


def test_missing_robot_file(session, capsys):
    rc = main(["calibrate", str(session / "measurements.csv"), "--robot", "nope.json"])
    assert rc == EXIT_INPUT and "nope.json" in capsys.readouterr().err


def test_refusal_exits_3_with_advice(session, tmp_path, capsys):
    lines = (session / "measurements.csv").read_text().splitlines()
    (tmp_path / "few.csv").write_text("\n".join(lines[:12]) + "\n")
    rc = main(
        [
            "calibrate",
            str(tmp_path / "few.csv"),
            "--robot",
            str(session / "robot.json"),
            "--model",
            "42",
        ]
    )
    assert rc == EXIT_REFUSED
    assert "cannot calibrate every leg" in capsys.readouterr().err


def test_shipped_example_is_the_simulators_output(tmp_path):
    """examples/left-hand-sim is exactly what `hexcal simulate --seed 1` writes."""
    if not EXAMPLE.exists():
        pytest.skip("running from an installed copy without the repository's examples/")
    assert main(["simulate", "--out", str(tmp_path), "--seed", "1"]) == 0
    for name in ("robot.json", "measurements.csv", "instruments.json", "truth.json"):
        assert (tmp_path / name).read_text() == (EXAMPLE / name).read_text(), name


def test_calibrate_with_an_added_effect(tmp_path, capsys):
    import numpy as np

    from hexcal.effects.inject import effect_hook
    from hexcal.instruments import EncoderNoise, Instruments, TrackerNoise, save_instruments
    from hexcal.measurements import write_measurements
    from hexcal.robot import save_robot
    from hexcal.session_sim import SessionPlan, perturbed_truth, simulate_session
    from hexcal.study import left_hand

    design = left_hand()
    rng = np.random.default_rng(2)
    truth = perturbed_truth(design, rng, SessionPlan())
    gains = np.array([800.0, -600.0, 700.0, -900.0, 500.0, -400.0])
    meas, _ = simulate_session(
        design, 2, SessionPlan(), effects=[effect_hook("gain", gains, truth)], truth=truth
    )
    write_measurements(meas, tmp_path / "m.csv")
    save_robot(design, tmp_path / "r.json")
    save_instruments(
        Instruments(
            tracker=TrackerNoise(position_sigma_mm=0.01, orientation_sigma_deg=0.002),
            encoders=EncoderNoise(reading_sigma_mm=0.002),
        ),
        tmp_path / "i.json",
    )
    rc = main(
        [
            "calibrate",
            str(tmp_path / "m.csv"),
            "--robot",
            str(tmp_path / "r.json"),
            "--instruments",
            str(tmp_path / "i.json"),
            "--add",
            "gain",
            "--json",
        ]
    )
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["effects"] == ["gain"]
    est = {p["name"]: p for p in out["parameters"]}
    for k, g in enumerate(gains, start=1):
        p = est[f"gain.g{k}"]
        assert abs(p["value"] - g) < 4 * p["sigma"]
    assert np.max(np.abs(np.array(out["base_points"]) - truth.a)) < 0.2
