"""Plausible ranges are priors: defaults that match real hardware, robot.json's ``plausible``
replacing them (validated), and a value outside its range flagged with what it means — never a
verdict."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import instruments

from hexcal.diagnosis import diagnose
from hexcal.effects import get_effect
from hexcal.estimate.effect_fit import Problem, fit_model
from hexcal.estimate.model_file import CalibratedRobot, load_robot, parse_model
from hexcal.estimate.predict import LegModel
from hexcal.model.robot import Robot, RobotFileError, save_robot
from hexcal.sim.inject import effect_hook, realistic_values
from hexcal.sim.session_sim import SessionPlan, perturbed_truth, simulate_session

JUGGLEBOT = Path(__file__).parents[1] / "examples" / "jugglebot"
MAP = JUGGLEBOT / "map.toml"


def _with(design: Robot, **keys) -> Robot:
    return Robot.model_validate({**json.loads(design.to_json()), **keys})


def test_defaults_match_real_hardware(design):
    ranges = {
        e: get_effect(e).params(design)[0].plausible
        for e in ("gain", "offset", "backlash", "thermal", "leadscrew")
    }
    assert ranges["gain"] == (-100_000.0, 100_000.0)  # ± 10 %: scales measured by hand
    assert ranges["offset"] == (-10.0, 10.0)  # relative to the design, legs measured by hand
    assert ranges["backlash"] == (0.0, 0.5)
    assert ranges["thermal"] == (-5.0, 40.0)
    assert ranges["leadscrew"] == (-0.1, 0.1)
    # Identifiability has its own scale, which a prior does not move.
    assert get_effect("gain").params(design)[0].resolution == 500.0
    wide = _with(design, plausible={"gain": [-1e6, 1e6]})
    assert get_effect("gain").params(wide)[0].resolution == 500.0


def test_robot_priors_replace_the_defaults_by_effect_then_by_parameter(design):
    robot = _with(
        design,
        plausible={
            "gain": [-20_000, 20_000],
            "gain.g1": [-80_000, 80_000],
            "offset": [-3, 3],
            "backlash": [0, 0.1],
        },
    )
    gain = {s.name: s.plausible for s in get_effect("gain").params(robot)}
    assert gain["gain.g1"] == (-80_000.0, 80_000.0)
    assert gain["gain.g2"] == (-20_000.0, 20_000.0)
    assert get_effect("offset").params(robot)[3].plausible == (-3.0, 3.0)
    assert get_effect("backlash").params(robot)[0].plausible == (0.0, 0.1)
    assert get_effect("thermal").params(robot)[0].plausible == (-5.0, 40.0)  # untouched
    # The predictor reads its specs from the same place.
    model = LegModel(robot, ("gain",), np.zeros(6))
    assert model.specs[0].plausible == (-80_000.0, 80_000.0)


@pytest.mark.parametrize(
    "plausible, match",
    [
        (
            {"gian": [0, 1]},
            r"field plausible: unknown effect or parameter 'gian'; known: .*gain \(gain\.g1 … gain\.g6\)",
        ),
        ({"gain.g7": [0, 1]}, r"unknown effect or parameter 'gain\.g7'"),
        (
            {"compliance.c": [0, 1]},
            r"without platform_mass_kg the compliance parameter is compliance\.cm",
        ),
        ({"gain": [5, -5]}, r"field plausible: gain is \[low, high\] with low < high"),
        ({"gain": [0, 0]}, r"low < high"),
        ({"gain": [1]}, r"field plausible\.gain"),
        ({"gain": [0, 1e300]}, r"field plausible\.gain\.1"),
        ({"gain": "wide"}, r"field plausible\.gain"),
    ],
)
def test_bad_priors_are_refused_with_the_field(tmp_path, design, plausible, match):
    data = json.loads(design.to_json())
    data["plausible"] = plausible
    path = tmp_path / "robot.json"
    path.write_text(json.dumps(data))
    with pytest.raises(RobotFileError, match=match):
        load_robot(path)


def test_non_finite_prior_is_refused(tmp_path, design):
    text = design.to_json().rstrip().rstrip("}") + ', "plausible": {"gain": [0, NaN]}}'
    (tmp_path / "r.json").write_text(text)
    with pytest.raises(RobotFileError, match="NaN"):
        load_robot(tmp_path / "r.json")


def test_priors_and_dead_band_round_trip_and_ride_in_the_model_file(tmp_path, design):
    robot = _with(
        design,
        platform_mass_kg=12.0,
        plausible={"compliance.c": [0, 3], "offset3": [-1, 1]},
        backlash_deadband_mm=0.004,
    )
    save_robot(robot, tmp_path / "r.json")
    back = load_robot(tmp_path / "r.json")
    assert back.plausible == {"compliance.c": [0.0, 3.0], "offset3": [-1.0, 1.0]}
    assert back.backlash_deadband_mm == 0.004
    data = json.loads(back.to_json())
    data["calibration"] = {
        "format": "hexcal-calibrated-model",
        "format_version": 1,
        "model": "Model 42 + backlash",
        "kind": 42,
        "effects": [
            {
                "name": "backlash",
                "parameters": [
                    {"name": f"backlash.beta{k}", "value": 0.003, "unit": "mm"} for k in range(1, 7)
                ],
            }
        ],
        "fit": {"poses": 10},
        "provenance": {"poses": 10},
    }
    model = parse_model(data, "calibrated.json")
    assert isinstance(model, CalibratedRobot)
    assert model.leg_model().robot.backlash_deadband_mm == 0.004
    assert model.plain_robot().plausible == back.plausible


def test_a_value_outside_its_range_is_flagged_with_what_it_means_not_a_verdict(design):
    """A hidden gain of a few hundred ppm under a prior of ± 100 ppm: still named `gain` (the
    flag is not a verdict, and identifiability does not move with the prior), and the fit with
    gain flags the values outside with the scale error they mean."""
    design = design.model_copy(update={"platform_mass_kg": 20.0})
    rng = np.random.default_rng(300)
    plan = SessionPlan(temperature_rise_k=5.0)
    truth = perturbed_truth(design, rng, plan)
    values = realistic_values("gain", rng, truth)
    meas, _ = simulate_session(
        design, 300, plan, effects=[effect_hook("gain", values, truth)], truth=truth
    )
    narrow = _with(design, plausible={"gain": [-100, 100]})
    before = diagnose(meas, narrow, 42, instruments=instruments())
    assert before.verdict == "gain"
    after = diagnose(
        meas, narrow, 42, add=["gain"], instruments=instruments(), problem=before.problem
    )
    flagged = [p.name for p in after.fit.nonphysical()]
    assert flagged == [f"gain.g{k}" for k in range(1, 7) if abs(values[k - 1]) > 100]
    note = next(n for n in after.fit.notes if n.startswith("gain.g1 = "))
    assert "is outside its plausible range [−100, 100] ppm" in note
    assert "% scale error of leg 1 — check the leg's mm-per-count" in note
    assert note.endswith("or set plausible in robot.json if this hardware allows it")
    assert after.verdict == "none"


@pytest.fixture(scope="module")
def jugglebot():
    from hexcal.io.log_import import import_log

    meas = import_log(JUGGLEBOT / "108_calibration_poses.csv", MAP)
    return meas, load_robot(JUGGLEBOT / "design-robot.json")


def test_jugglebot_scales_several_per_cent_off_are_plausible(jugglebot):
    """The real belt/screw-driven platform: every leg's scale within the ± 10 % a hand-measured
    scale allows (leg 1's is 5.5 % off), no gain flagged; a tighter prior set in robot.json (a
    factory encoder's) flags leg 1 with what it means."""
    meas, design = jugglebot
    fit = fit_model(Problem.build(meas, design, None), ("offset", "gain"), cross_validate=False)
    assert not [p.name for p in fit.nonphysical() if p.name.startswith("gain")]
    g1 = next(p for p in fit.params if p.name == "gain.g1")
    assert -60_000 < g1.value < -50_000
    tight = _with(design, plausible={"gain": [-50_000, 50_000]})
    fit = fit_model(Problem.build(meas, tight, None), ("offset", "gain"), cross_validate=False)
    assert [p.name for p in fit.nonphysical() if p.name.startswith("gain")] == ["gain.g1"]
    assert any(
        n.startswith("gain.g1 = −5")
        and "is outside its plausible range [−50,000, 50,000] ppm: a 5." in n
        and "% scale error of leg 1 — check the leg's mm-per-count, or set plausible in robot.json"
        in n
        for n in fit.notes
    ), fit.notes


def test_an_unknown_prior_key_in_a_session_file_is_refused_and_the_file_kept(tmp_path, design):
    """The key check runs on every reader of a robot, the session file's included."""
    from hexcal.io.measurements_csv import read_measurements
    from hexcal.procedure.session import Session, SessionFile, SessionFileError, load_session

    meas = read_measurements(Path(__file__).parents[1] / "examples/left-hand-sim/measurements.csv")
    path = tmp_path / "s.json"
    SessionFile.create(path, Session.from_measurements(meas, design))
    data = json.loads(path.read_text())
    data["robot"]["plausible"] = {"gian": [0, 1]}
    path.write_text(json.dumps(data))
    before = path.read_bytes()
    with pytest.raises(SessionFileError, match=r"s\.json: field plausible: unknown .*'gian'"):
        load_session(path)
    assert path.read_bytes() == before
