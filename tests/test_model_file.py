"""calibrated.json: the calibrated model as one file — written by ``calibrate --out``, read
back wherever a robot is read, predicting exactly what the fit predicted."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hexcal.app.cli import main
from hexcal.app.workflow import calibrate_model, read_inputs
from hexcal.effects import CATALOGUE
from hexcal.estimate.model_file import CalibratedRobot, leg_model_of, load_model, load_robot
from hexcal.model.robot import Robot, RobotFileError
from hexcal.sim.robots import left_hand
from hexcal.sim.session_sim import SessionPlan, write_session_dir

#: A short session (4 poses per clamped step, 30 free) keeps each calibration quick.
PLAN = SessionPlan(n_type_i=4, n_type_ii=4, n_type_iii=4, n_free=30)


def _session(tmp_path, effect: str):
    design = left_hand().model_copy(update={"platform_mass_kg": 30.0})
    out = write_session_dir(tmp_path / effect, design, 3, PLAN, effect)
    return read_inputs(out / "measurements.csv", out / "robot.json", out / "instruments.json")


ROBOT_EFFECTS = sorted(
    e for e, eff in CATALOGUE.items() if e != "offset" and not eff.of_the_session
)


@pytest.mark.parametrize("effect", ROBOT_EFFECTS)
def test_the_file_predicts_exactly_what_the_fit_predicted(tmp_path, effect):
    """For every catalogue effect: Model 42 + the effect, with the clamp rows, written to
    calibrated.json and read back, gives the fit's own residuals to 1e-9 mm — the effects that
    use the geometry (thermal, compliance) are evaluated at the calibrated one in both."""
    inp = _session(tmp_path, effect)
    result = calibrate_model(inp, 42, effects=(effect,))
    path = tmp_path / "cal.json"
    path.write_text(result.file.to_json())
    back = load_model(path)
    assert isinstance(back, CalibratedRobot) and back == result.file
    assert back.calibration.model == f"Model 42 + {effect}"
    model = leg_model_of(back)
    assert model.effects == (effect,)
    fit = result.calibration.residuals
    assert np.abs(model.residuals(inp.meas) - fit).max() < 1e-9
    # Values, sigmas and units as fitted.
    ref = result.calibration.refinement
    for rec in back.calibration.effects[0].parameters:
        i = ref.names.index(rec.name)
        assert rec.value == ref.x[i] and rec.sigma == pytest.approx(ref.sigma[i])
        assert rec.unit


def test_the_file_is_a_robot_json_and_records_its_provenance(tmp_path):
    inp = _session(tmp_path, "gain")
    result = calibrate_model(inp, 42, effects=("gain",))
    data = json.loads(result.file.to_json())
    # Any robot.json reader finds the calibrated geometry where robot.json has it.
    plain = Robot.model_validate({k: v for k, v in data.items() if k != "calibration"})
    assert np.allclose(plain.a, result.calibration.robot.a)
    cal = data["calibration"]
    assert cal["format"] == "hexcal-calibrated-model" and cal["format_version"] == 3
    assert cal["fit"]["poses"] == len(inp.meas) == cal["provenance"]["poses"]
    assert {i["role"] for i in cal["provenance"]["inputs"]} == {
        "measurements",
        "robot",
        "instruments",
    }
    assert all(len(i["sha256"]) == 64 for i in cal["provenance"]["inputs"])
    assert cal["noise"]["tracker"]["position_sigma_mm"] == inp.instruments.sigma_position_mm
    models = [a["model"] for a in cal["accuracy"]]
    assert models == ["design (drawing)", "Model 42", "Model 42 + gain"]
    assert cal["accuracy"][-1]["position_rms_mm"] < cal["accuracy"][0]["position_rms_mm"]
    assert "NaN" not in result.file.to_json() and "Infinity" not in result.file.to_json()


def test_load_robot_reads_the_geometry_and_refuses_a_newer_format(tmp_path):
    inp = _session(tmp_path, "gain")
    result = calibrate_model(inp, 42, effects=("gain",))
    path = tmp_path / "cal.json"
    path.write_text(result.file.to_json())
    robot = load_robot(path)
    assert type(robot) is Robot and "calibration" not in robot.model_dump()
    assert robot == result.calibration.robot.model_copy(update={"name": robot.name})
    data = json.loads(path.read_text())
    data["calibration"]["format_version"] = 7
    path.write_text(json.dumps(data))
    with pytest.raises(RobotFileError, match=r"format version 7.*upgrade hexcal"):
        load_robot(path)
    data["calibration"]["format_version"] = 3  # the version written
    data["calibration"]["effects"][0]["parameters"].pop()
    path.write_text(json.dumps(data))
    with pytest.raises(RobotFileError, match=r"calibration\.effects: .*take 6 parameter values"):
        load_model(path)


def test_a_calibrated_model_given_as_robot_brings_its_effects(tmp_path, capsys):
    """``calibrate --robot calibrated.json`` refits the same model (its effects included) and
    reaches the same optimum."""
    inp = _session(tmp_path, "gain")
    result = calibrate_model(inp, 42, effects=("gain",))
    path = tmp_path / "cal.json"
    path.write_text(result.file.to_json())
    again = read_inputs(inp.files["measurements"], path, inp.files["instruments"])
    assert again.model_effects == ("gain",)
    assert (
        main(
            [
                "calibrate",
                str(inp.files["measurements"]),
                "--robot",
                str(path),
                "--instruments",
                str(inp.files["instruments"]),
                "--json",
            ]
        )
        == 0
    )
    out = json.loads(capsys.readouterr().out)
    assert out["model_name"] == "Model 42 + gain"
    assert out["rms_mm"] == pytest.approx(result.calibration.rms_mm, rel=1e-6)


@pytest.mark.parametrize(
    ("version", "match"),
    [
        ('"1"', r"field calibration\.format_version: '1' is not a format version"),
        ("0", r"field calibration\.format_version: 0 is not a format version"),
        ("true", r"field calibration\.format_version: true is not a format version"),
        ("1" + "0" * 30, r"format version 1000000000000000000000000000000; .*upgrade hexcal"),
    ],
)
def test_a_format_version_that_is_not_one_is_named(tmp_path, version, match):
    text = (Path(__file__).parent / "data" / "calibrated.json").read_text()
    path = tmp_path / "calibrated.json"
    path.write_text(text.replace('"format_version": 1', f'"format_version": {version}'))
    with pytest.raises(RobotFileError, match=match):
        load_model(path)


def test_an_effect_of_the_session_is_fitted_but_not_shipped(tmp_path):
    """A drifting tracker is fitted with the geometry, but it belongs to that session: the
    calibrated model leaves it out and says so."""
    inp = _session(tmp_path, "drift")
    result = calibrate_model(inp, 42, effects=("drift",))
    assert result.calibration.effects == ("drift",)
    assert result.file.calibration.effects == []
    assert "fitted with drift: the session's, left out" in result.file.calibration.model
