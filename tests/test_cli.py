"""The hexcal command line: calibrate (text, JSON, --out), simulate, errors on stderr."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hexcal.app.cli import EXIT_INPUT, EXIT_REFUSED, main
from hexcal.estimate.model_file import load_robot

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

    from hexcal.io.measurements import write_measurements
    from hexcal.model.instruments import EncoderNoise, Instruments, TrackerNoise, save_instruments
    from hexcal.model.robot import save_robot
    from hexcal.sim.inject import effect_hook
    from hexcal.sim.robots import left_hand
    from hexcal.sim.session_sim import SessionPlan, perturbed_truth, simulate_session

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


def _base(session) -> list[str]:
    return [
        str(session / "measurements.csv"),
        "--robot",
        str(session / "robot.json"),
        "--instruments",
        str(session / "instruments.json"),
    ]


def test_out_never_overwrites_an_input_and_needs_force_over_a_file(session, tmp_path, capsys):
    robot = tmp_path / "robot.json"
    robot.write_text((session / "robot.json").read_text())
    args = [str(session / "measurements.csv"), "--robot", str(robot)]
    assert main(["calibrate", *args, "--out", str(robot)]) == EXIT_INPUT
    assert "this is the robot input" in capsys.readouterr().err
    assert robot.read_text() == (session / "robot.json").read_text()
    meas = session / "measurements.csv"
    before = meas.read_text()
    assert main(["diagnose", *args, "--residuals", str(meas)]) == EXIT_INPUT
    assert "this is the measurements input" in capsys.readouterr().err
    assert meas.read_text() == before
    out = tmp_path / "cal.json"
    out.write_text("{}")
    assert main(["calibrate", *args, "--out", str(out)]) == EXIT_INPUT
    assert "pass --force" in capsys.readouterr().err
    assert main(["calibrate", *args, "--out", str(out), "--force"]) == 0
    assert "calibration" in json.loads(out.read_text())


def test_diagnose_auto_out_writes_the_model_with_its_effects(tmp_path, capsys):
    sim = tmp_path / "sim"
    assert main(["simulate", "--out", str(sim), "--seed", "3", "--effect", "gain"]) == 0
    capsys.readouterr()
    out = tmp_path / "cal.json"
    assert main(["diagnose", *_base(sim), "--auto", "--out", str(out), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert [s["verdict"] for s in result["steps"]] == ["gain", "none"]
    assert result["written"]["model"] == "Model 42 + gain"
    for s in result["steps"]:
        assert s["pose_accuracy"]["heldout"] and s["pose_accuracy"]["position_rms_mm"] > 0
    assert result["design_pose_accuracy"]["model"] == "design (drawing)"
    cal = json.loads(out.read_text())["calibration"]
    assert [e["name"] for e in cal["effects"]] == ["gain"]
    assert [a["model"] for a in cal["accuracy"]] == [
        "design (drawing)",
        "Model 42",
        "Model 42 + gain",
    ]
    # The text shows the pose error beside the leg-length RMS, model by model.
    assert main(["diagnose", *_base(sim), "--auto"]) == 0
    text = capsys.readouterr().out
    assert "the error as effects are added" in text and "pose floor (noise alone)" in text
    assert "design (drawing, all poses)" in text


def test_predict_round_trips_through_csv(session, tmp_path, capsys):
    """readings → poses → readings through the CLI, with the model of a calibration."""
    cal = tmp_path / "cal.json"
    assert main(["calibrate", *_base(session), "--add", "gain", "--out", str(cal)]) == 0
    poses = tmp_path / "poses.csv"
    table = session / "measurements.csv"
    assert main(["predict", str(cal), str(table), "--to", "pose", "--out", str(poses)]) == 0
    readings = tmp_path / "readings.csv"
    assert main(["predict", str(cal), str(poses), "--to", "readings", "--out", str(readings)]) == 0
    capsys.readouterr()
    from hexcal.io.measurements_csv import read_measurements

    a, b = read_measurements(table), read_measurements(readings)
    assert np.abs(a.readings - b.readings).max() < 1e-6
    # Without --to, a table with both kinds of columns is refused with what to do.
    assert main(["predict", str(cal), str(table)]) == EXIT_INPUT
    assert "--to pose or --to readings" in capsys.readouterr().err


def test_predict_names_a_bad_cell_and_a_row_out_of_the_workspace(session, tmp_path, capsys):
    bad = tmp_path / "r.csv"
    bad.write_text("rho1,rho2,rho3,rho4,rho5,rho6\n50,50,50,50,50,50\n50,50,x,50,50,50\n")
    robot = str(session / "robot.json")
    assert main(["predict", robot, str(bad)]) == EXIT_INPUT
    assert "r.csv: line 3, column 'rho3': 'x' is not a number" in capsys.readouterr().err
    bad.write_text("rho1,rho2,rho3,rho4,rho5,rho6\n50,50,50,50,50,50\n0,0,0,900,900,900\n")
    assert main(["predict", robot, str(bad)]) == EXIT_INPUT
    assert "row 2 are outside the workspace" in capsys.readouterr().err


def test_validate_json_has_the_contract(session, capsys):
    assert (
        main(
            [
                "validate",
                str(session / "robot.json"),
                str(session / "measurements.csv"),
                "--instruments",
                str(session / "instruments.json"),
                "--json",
            ]
        )
        == 0
    )
    v = json.loads(capsys.readouterr().out)
    for key in (
        "position_rms_mm",
        "position_p95_mm",
        "orientation_rms_deg",
        "leg_rms_mm",
        "noise_floor_mm",
        "verdict",
    ):
        assert key in v
    assert v["model"].startswith("design") and v["verdict"] != "none"


@pytest.mark.parametrize("group", ["devices", "session"])
def test_a_command_group_alone_prints_its_subcommands(group, capsys):
    from hexcal.app.cli import main

    assert main([group]) == 0
    out = capsys.readouterr().out
    assert f"usage: hexcal {group}" in out
    assert ("can-setup" in out) if group == "devices" else ("export" in out)


def test_hexcal_alone_prints_its_commands(capsys):
    from hexcal.app.cli import COMMANDS, main

    assert main([]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: hexcal")
    assert len(COMMANDS) > 5
    for command in ("calibrate", "diagnose", "run", "demo", "devices", "session"):
        assert f"\n    {command}" in out


def test_every_option_of_every_command_has_a_help_line():
    import argparse

    from hexcal.app.cli import build_parser

    missing = []

    def walk(parser: argparse.ArgumentParser, path: str) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, child in action.choices.items():
                    walk(child, f"{path} {name}")
            elif not isinstance(action, argparse._HelpAction) and not action.help:
                missing.append(f"{path} {'/'.join(action.option_strings) or action.dest}")

    walk(build_parser(), "hexcal")
    assert missing == []
