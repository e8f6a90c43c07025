"""One chain: ``calibrate --add`` locates what ``diagnose --auto`` names by the same search
(:mod:`hexcal.diagnosis.locators`), so both write the same model — on the Jugglebot's real
session, on a simulated session hiding a zero step, and on one whose tracker was knocked."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hexcal.app.cli import main
from hexcal.app.workflow import Inputs, calibrate_model, diagnose_chain, model_of
from hexcal.diagnosis.locators import LOCATORS
from hexcal.effects import CATALOGUE
from hexcal.model.robot import Robot
from hexcal.sim import verdict_cases as vc

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "jugglebot"
#: How closely the two files agree, mm (and in each parameter's unit): one fit, one seed.
SAME = 1e-9


def _numbers(model: dict) -> dict[str, np.ndarray]:
    """The model's geometry and every effect parameter's value, by name."""
    out = {
        k: np.asarray(model[k], float) for k in ("base_points", "platform_points", "leg_offsets")
    }
    for e in model["calibration"]["effects"]:
        for p in e["parameters"]:
            out[p["name"]] = np.asarray(p["value"], float)
    return out


def _assert_same(a: dict, b: dict) -> None:
    assert a.get("zero_steps") == b.get("zero_steps")
    assert a.get("frame_steps") == b.get("frame_steps")
    assert a["calibration"]["model"] == b["calibration"]["model"]
    na, nb = _numbers(a), _numbers(b)
    assert na.keys() == nb.keys()
    for k in na:
        assert np.max(np.abs(na[k] - nb[k])) <= SAME, k


def test_every_located_effect_is_a_catalogue_effect_with_a_robot_json_key():
    for name, loc in LOCATORS.items():
        assert name in CATALOGUE and loc.key in Robot.model_fields
        assert loc.none_found.startswith(f"{name}: ")


def test_the_jugglebot_s_auto_chain_and_calibrate_add_write_the_same_model(
    tmp_path, capsys, registry_restored
):
    table, robot = tmp_path / "jb.csv", EXAMPLE / "design-robot.json"
    log, mapping = EXAMPLE / "108_calibration_poses.csv", EXAMPLE / "map.toml"
    assert main(["import", str(log), "--map", str(mapping), "--out", str(table)]) == 0
    capsys.readouterr()
    auto, added = tmp_path / "auto.json", tmp_path / "added.json"
    found = tmp_path / "effects"
    args = ["diagnose", str(table), "--robot", str(robot), "--auto", "--explore", str(found)]
    assert main([*args, "--out", str(auto), "--json"]) == 0
    steps = json.loads(capsys.readouterr().out)["steps"]
    effects = steps[-1]["effects"][1:]  # what the chain added, step by step, after the offsets
    # gain; then the legs' load: the catalogue's compliance closes it, but the explorer's
    # bending curve (force × length²) predicts the held-out poses better, and its file carries
    # the chain on (a zero step of leg 2 after it).
    assert effects[:2] == ["gain", "by_force_x_length2"] and steps[-1]["verdict"] == "none"
    assert [s["verdict"] for s in steps[:2]] == ["gain", "unexplained"]
    files = [str(p) for p in sorted(found.glob("*.py"))]
    rc = main(
        ["calibrate", str(table), "--robot", str(robot), "--add", *effects, "--effects", *files]
        + ["--out", str(added)]
    )
    assert rc == 0
    _assert_same(json.loads(auto.read_text()), json.loads(added.read_text()))


def test_a_simulated_zero_step_auto_chain_and_calibrate_agree():
    c = vc.zero_jump(3)
    inp = Inputs(c.meas, c.design, c.instruments, "stated", "jump")
    chain = diagnose_chain(inp, 42, auto=True)
    assert [d.verdict for d in chain] == ["zero_step", "none"]
    auto = model_of(inp, chain).file
    added = calibrate_model(inp, 42, effects=("zero_step",)).file
    _assert_same(json.loads(auto.to_json()), json.loads(added.to_json()))
    (step,) = added.zero_steps or []
    assert step.leg == c.jump_leg


def test_a_knocked_tracker_auto_chain_and_calibrate_agree():
    c = vc.foreign("tracker knocked", 1)
    inp = Inputs(c.meas, c.design, c.instruments, "stated", "knock")
    chain = diagnose_chain(inp, 42, auto=True)
    assert [d.verdict for d in chain] == ["frame_step", "none"]
    assert abs(chain[0].frame.index - c.frame_row) <= 3
    auto = model_of(inp, chain).file
    added = calibrate_model(inp, 42, effects=("frame_step",)).file
    _assert_same(json.loads(auto.to_json()), json.loads(added.to_json()))
    assert added.frame_steps and len(added.frame_steps) == 1


def test_calibrate_add_zero_step_where_no_leg_jumped_is_refused_clearly():
    c = vc.absorbed("tracker scale", 5)
    inp = Inputs(c.meas, c.design, c.instruments, "stated", "clean")
    with pytest.raises(ValueError, match="zero_step: no change of a leg's zero is found"):
        calibrate_model(inp, 42, effects=("zero_step",))
