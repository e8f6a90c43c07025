"""``hexcal demo``: the whole calibration on mock hardware, through the real drivers, headless.

One run (backlash hidden: the effect that most needs the motion history right) checked against
the simulator's truth; its session file then goes through export, import and the CLI."""

from __future__ import annotations

import json

import pytest
from statcheck import heldout_limit, heldout_sd_rel_bound, pose_floor_limit

from hexcal.app.cli import main
from hexcal.app.demo import DemoSettings, demo_text, run_demo
from hexcal.estimate.model_file import load_model
from hexcal.io.measurements_csv import read_measurements
from hexcal.procedure.session import load_session


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    path = tmp_path_factory.mktemp("demo") / "session.json"
    settings = DemoSettings(
        seed=7, effect="backlash", poses_per_step=4, free_poses=14, session_path=path
    )
    return run_demo(settings)


@pytest.mark.slow
def test_the_diagnosis_finds_the_hidden_effect_and_the_error_falls(demo):
    d = demo["diagnosis"]
    assert demo["hidden_effect"]["name"] == "backlash" and d["found_hidden_effect"]
    before, after = d["steps"]
    assert after["effects"] == ["backlash"] and after["verdict"] == "none"
    # The top-level verdict is where the chain ends, the chain beside it (not its first step's).
    assert d["verdict"] == "none" and d["chain"] == ["backlash", "none"]
    assert d["named"] == "backlash"
    assert after["cv_rms_mm"] < 0.5 * before["cv_rms_mm"]
    # at the floor: within 3σ of a correct model's (σ from the pose count, tests/statcheck.py);
    # Model 42 + backlash, 48 parameters
    m = demo["poses"]
    limit = heldout_limit(after["noise_floor_mm"], heldout_sd_rel_bound(m), 6 * m, 48)
    assert after["cv_rms_mm"] < limit, (after, limit)


@pytest.mark.slow
def test_with_the_effect_the_geometry_is_the_truth_within_its_uncertainty(demo):
    after = demo["with_effect_vs_truth"]
    assert after["parameters"] == 42
    assert after["mahalanobis2_p"] > 1e-3, after  # χ² with 42 dof
    assert after["max_error_mm"] < demo["model_42_vs_truth"]["max_error_mm"]


@pytest.mark.slow
def test_the_session_file_has_everything_and_exports_losslessly(demo, tmp_path, capsys):
    s = load_session(demo["session"])
    assert len(s.poses) == demo["poses"] == 1 + 12 * 4 + 14
    assert {p.step for p in s.poses} >= {"home", "leg6-length", "free"}
    assert all(p.tracker_samples and p.leg_samples for p in s.poses)
    assert s.instruments is not None and s.devices is not None and s.procedure["model"] == 42
    assert [r.kind for r in s.results] == ["calibration", "diagnosis"]
    # Every step keeps its whole model: Model 42, then Model 42 + backlash with its values.
    first, last = (r.calibrated for r in s.results)
    assert first.calibration.model == "Model 42" and not first.calibration.effects
    assert last.calibration.model == "Model 42 + backlash"
    assert main(["session", "export", demo["session"], "--out", str(tmp_path / "x")]) == 0
    exported = read_measurements(tmp_path / "x" / "measurements.csv")
    assert exported == s.measurements()
    shipped = load_model(tmp_path / "x" / "calibrated.json")
    assert shipped == last
    betas = [p.value for p in shipped.calibration.effects[0].parameters]
    assert [p["value"] for p in demo["calibrated"]["effects"][0]["parameters"]] == betas
    new = tmp_path / "again.json"
    args = [str(tmp_path / "x" / "measurements.csv"), "--robot", str(tmp_path / "x" / "robot.json")]
    assert main(["session", "import", *args, "--out", str(new)]) == 0
    assert load_session(new).measurements() == exported
    capsys.readouterr()
    assert main(["calibrate", demo["session"], "--add", "backlash", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["model"] == 42


@pytest.mark.slow
def test_the_pose_error_falls_to_the_floor(demo):
    """Pose error (the pose from the readings against the tracker): the drawing, Model 42 and
    Model 42 + backlash on held-out poses; the last at the noise floor (within 3σ of a correct
    model's, σ from the pose count: tests/statcheck.py)."""
    design, model42, added = demo["pose_accuracy"]
    assert design["model"] == "design (drawing)" and added["model"] == "Model 42 + backlash"
    assert design["position_rms_mm"] > model42["position_rms_mm"] > added["position_rms_mm"]
    limit = pose_floor_limit(added["floor_position_rms_mm"], added["poses"], 48)
    assert added["position_rms_mm"] < limit, (added, limit)
    assert model42["position_rms_mm"] > 2 * added["floor_position_rms_mm"]


@pytest.mark.slow
def test_demo_text_says_what_happened(demo):
    text = demo_text(demo)
    assert "hidden effect: backlash" in text and "the diagnosis found it" in text
    assert f"hexcal diagnose {demo['session']} --add backlash" in text


def test_schema_command(capsys):
    assert main(["schema"]) == 0
    schema = json.loads(capsys.readouterr().out)
    assert schema["title"] == "Session"
