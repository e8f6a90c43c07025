"""The data's own consistency, before any fit: quaternions in x,y,z,w order, a sign-flipped
leg, readings in cm, a table in cm, swapped columns, a drawing in cm or inches and a leg offset
far from the drawing are each named with the fix; a clean session, the real Jugglebot and a
table with typos (the outlier screen's) are not; the per-leg scale matches a simulated gain."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from hexcal.app.cli import EXIT_DRAWING, main
from hexcal.estimate.consistency import ORDER_MIN_MM, check_consistency
from hexcal.estimate.model_file import load_robot
from hexcal.io.json_out import loads_strict
from hexcal.io.measurements_csv import read_measurements

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "left-hand-sim"
JUGGLEBOT = ROOT / "examples" / "jugglebot"


def _table(tmp_path: Path, name: str, edit) -> Path:
    """The example's table with each row (a dict of text) edited."""
    rows = list(csv.DictReader((EXAMPLE / "measurements.csv").open()))
    out = tmp_path / name
    with out.open("w", newline="") as fh:
        w = csv.DictWriter(fh, list(rows[0]))
        w.writeheader()
        w.writerows(edit(dict(r)) for r in rows)
    return out


def _scaled(row: dict, columns, factor: float) -> dict:
    return row | {c: repr(float(row[c]) * factor) for c in columns}


READINGS = [f"rho{k}" for k in range(1, 7)]
EDITS = {
    "xyzw": lambda r: r | {"qw": r["qx"], "qx": r["qy"], "qy": r["qz"], "qz": r["qw"]},
    "sign": lambda r: r | {"rho3": repr(-float(r["rho3"]))},
    "cm": lambda r: _scaled(r, READINGS, 0.1),
    "cm-table": lambda r: _scaled(r, [*READINGS, "x", "y", "z"], 0.1),
    "swapped": lambda r: r | {"rho1": r["rho2"], "rho2": r["rho1"]},
}
#: case -> (the cause found, whether it rests on the drawing, text the message holds)
EXPECTED = {
    "xyzw": ("quaternion-order", False, "quaternions look scalar-last (x, y, z, w)"),
    "sign": ("sign", False, "leg 3: the reading falls as the leg lengthens"),
    "cm": ("units", False, "readings in cm against positions in mm?"),
    "cm-table": ("geometry-scale", True, "are the table's positions and readings in cm?"),
    "swapped": ("swapped", True, "legs 1 and 2 look swapped"),
}


def _args(table: Path, robot: Path = EXAMPLE / "robot.json") -> list[str]:
    return [str(table), "--robot", str(robot), "--instruments", str(EXAMPLE / "instruments.json")]


@pytest.mark.parametrize("case", sorted(EDITS))
def test_each_slip_is_found_and_named(tmp_path, case):
    table = _table(tmp_path, f"{case}.csv", EDITS[case])
    c = check_consistency(read_measurements(table), load_robot(EXAMPLE / "robot.json"))
    cause, drawing, text = EXPECTED[case]
    assert [(f.cause, f.drawing) for f in c.findings] == [(cause, drawing)]
    assert text in c.findings[0].text


@pytest.mark.parametrize("case", [*sorted(EDITS), "clean"])
def test_a_long_session_is_judged_on_poses_spread_over_it(tmp_path, monkeypatch, case):
    """Beyond CHECK_POSES poses the check reads that many, spread evenly over the session (a
    120,000-pose recording): every slip is still named, a clean table still raises nothing.
    Here CHECK_POSES is lowered to 80 so that the example's table is a long session."""
    import hexcal.estimate.consistency as consistency

    monkeypatch.setattr(consistency, "CHECK_POSES", 80)
    table = _table(tmp_path, f"{case}.csv", EDITS.get(case, lambda r: r))
    meas = read_measurements(table)
    assert len(meas) > 2 * 80
    c = check_consistency(meas, load_robot(EXAMPLE / "robot.json"))
    if case == "clean":
        assert c.findings == []
    else:
        assert [f.cause for f in c.findings] == [EXPECTED[case][0]]


@pytest.mark.parametrize("case", ["xyzw", "sign", "cm"])
def test_the_command_line_refuses_them_with_exit_4_before_any_fit(tmp_path, case, capsys):
    """The slips of the fault campaign that ended as "did not converge" (exit 3) after seconds,
    or as a validation error of robot.json: now exit 4, the cause and the fix named, and with
    --no-drawing-check too (none of them rests on the drawing)."""
    table = _table(tmp_path, f"{case}.csv", EDITS[case])
    for extra in ([], ["--no-drawing-check"]):
        assert main(["calibrate", *_args(table), "--lengths-only", *extra]) == EXIT_DRAWING
        err = capsys.readouterr().err
        assert "nothing was fitted" in err and EXPECTED[case][2] in err, err


@pytest.mark.parametrize("case", ["swapped", "cm-table"])
def test_with_no_drawing_check_swapped_columns_and_a_table_in_cm_are_still_flagged(
    tmp_path, case, capsys
):
    table = _table(tmp_path, f"{case}.csv", EDITS[case])
    assert main(["calibrate", *_args(table)]) == EXIT_DRAWING
    assert EXPECTED[case][2] in capsys.readouterr().err
    assert main(["calibrate", *_args(table), "--no-drawing-check", "--json"]) == 0
    captured = capsys.readouterr()
    assert "warning (the drawing is not checked)" in captured.err
    assert EXPECTED[case][2] in captured.err
    out = loads_strict(captured.out)
    assert any(EXPECTED[case][2] in w for w in out["data_warnings"])


def _robot(tmp_path: Path, edit) -> Path:
    data = json.loads((EXAMPLE / "robot.json").read_text())
    edit(data)
    path = tmp_path / "robot.json"
    path.write_text(json.dumps(data))
    return path


def test_a_leg_offset_far_from_the_drawing_exits_4_at_once(tmp_path, capsys):
    """The 151.5 mm offset of the fault campaign: 21 s, exit 0 and NaN in the JSON; now exit 4,
    the leg and both offsets named, before any fit."""
    robot = _robot(tmp_path, lambda d: d["leg_offsets"].__setitem__(2, 152.5 + 151.5))
    code = main(["calibrate", *_args(EXAMPLE / "measurements.csv", robot), "--json"])
    assert code == EXIT_DRAWING
    captured = capsys.readouterr()
    assert captured.out == ""
    assert "leg 3's offset is 151.8 mm by the data but 304.0 mm in robot.json" in captured.err


@pytest.mark.parametrize(("factor", "unit"), [(0.1, "cm"), (1 / 25.4, "inches"), (0.001, "m")])
def test_a_drawing_in_other_units_is_recognised(tmp_path, capsys, factor, unit):
    def scale(d):
        d["base_points"] = (np.array(d["base_points"]) * factor).tolist()
        d["platform_points"] = (np.array(d["platform_points"]) * factor).tolist()
        d["leg_offsets"] = [o * factor for o in d["leg_offsets"]]
        d["home"]["position"] = [p * factor for p in d["home"]["position"]]

    robot = _robot(tmp_path, scale)
    assert main(["calibrate", *_args(EXAMPLE / "measurements.csv", robot)]) == EXIT_DRAWING
    err = capsys.readouterr().err
    assert f"robot.json looks {1 / factor:.4g}× too small for the data" in err, err
    assert f"is robot.json in {unit}?" in err


def test_clean_data_the_jugglebot_and_a_table_with_typos_raise_nothing(tmp_path, capsys):
    design = load_robot(EXAMPLE / "robot.json")
    clean = check_consistency(read_measurements(EXAMPLE / "measurements.csv"), design)
    assert clean.checked and clean.findings == []
    # The order as read fits at the noise: the other order is not read at all.
    assert clean.orders["wxyz"] < ORDER_MIN_MM and "xyzw" not in clean.orders
    assert main(["import", str(JUGGLEBOT / "108_calibration_poses.csv"), "--map",
                 str(ROOT / "examples" / "jugglebot" / "map.toml"), "--out",
                 str(tmp_path / "jb.csv")]) == 0  # fmt: skip
    real = check_consistency(
        read_measurements(tmp_path / "jb.csv"), load_robot(JUGGLEBOT / "design-robot.json")
    )
    assert real.checked and real.findings == []
    # Its hand-measured mm per revolution is a few per cent off: a gain, not a unit.
    assert all(1.0 < g.scale < 1.07 for g in real.legs)

    def typos(r):
        if r["pose_id"] == "50":
            r["rho2"] = repr(float(r["rho2"]) + 500)
        if r["pose_id"] == "80":
            r["x"] = repr(float(r["x"]) + 300)
        return r

    table = _table(tmp_path, "typos.csv", typos)
    assert check_consistency(read_measurements(table), design).findings == []
    assert main(["calibrate", *_args(table)]) == 2
    err = capsys.readouterr().err
    assert "2 pose(s) are gross outliers" in err and "--exclude-poses 50 80" in err


def test_the_per_leg_scale_matches_a_simulated_gain():
    """Truth from simulation: gains of −4..+5 % on a simulated session; each leg's scale is
    1 + g within 4 of its standard errors, and those errors are honest (mean z² near 1)."""
    from hexcal.sim.inject import effect_hook
    from hexcal.sim.robots import left_hand
    from hexcal.sim.session_sim import SessionPlan, perturbed_truth, simulate_session

    design = left_hand()
    z = []
    for seed in range(4):
        rng = np.random.default_rng(seed)
        truth = perturbed_truth(design, rng, SessionPlan())
        gains = rng.uniform(-40_000, 50_000, 6)  # ppm
        meas, _ = simulate_session(
            design, seed, effects=[effect_hook("gain", gains, truth)], truth=truth
        )
        c = check_consistency(meas, design)
        assert c.findings == []
        z += [
            (g.scale - (1 + gain * 1e-6)) / g.scale_sigma
            for g, gain in zip(c.legs, gains, strict=True)
        ]
    z = np.array(z)
    assert np.all(np.abs(z) < 4), z
    assert 0.3 < np.mean(z**2) < 3.0, np.mean(z**2)


def test_a_fit_that_diverges_is_named_a_divergence_with_its_likely_causes(tmp_path, monkeypatch):
    """Past the screen (here switched off), quaternions in x,y,z,w order make the fit diverge:
    it is called a divergence, never a validation error of robot.json, and the quaternion
    order leads the causes the data's signature ranks."""
    from hexcal.app import workflow
    from hexcal.vocabulary import ModelKind

    table = _table(tmp_path, "xyzw.csv", EDITS["xyzw"])
    inp = workflow.read_inputs(table, EXAMPLE / "robot.json", EXAMPLE / "instruments.json")
    monkeypatch.setattr(workflow, "screen_inputs", lambda inp: [])
    with pytest.raises((workflow.FitDiverged, workflow.FitFailed)) as info:
        workflow.calibrate_model(inp, ModelKind.M42, clamps=False)
    text = str(info.value)
    assert "field base_points" not in text and "robot geometry" not in text
    first = text.split("1. ", 1)[1]
    assert first.startswith("the quaternions look scalar-last"), text
    if isinstance(info.value, workflow.FitDiverged):
        assert "the fit diverged" in text and "not an error in the robot file" in text
