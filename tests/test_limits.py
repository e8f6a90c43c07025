"""The stroke as a fact (hexcal.diagnosis.limits): readings beyond ``leg_range_mm`` by more than
the noise are refused by calibrate and diagnose (exit 4), naming the legs, how far and the
likely cause; "at the end of its stroke" is said only of readings inside it; the advice never
asks for a key robot.json already has."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from hexcal.app.cli import main
from hexcal.app.commands.common import EXIT_DRAWING
from hexcal.diagnosis.limits import at_limits, beyond_stroke, end_margin_mm
from hexcal.estimate.model_file import load_robot
from hexcal.io.measurements_csv import read_measurements

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "left-hand-sim"
READINGS = [f"rho{k}" for k in range(1, 7)]
#: The example's readings span −2.2 .. 110.8 mm: a stroke that holds them all.
STROKE = [-5.0, 115.0]


def _robot(tmp_path: Path, stroke, offset_shift: float = 0.0) -> Path:
    d = json.loads((EXAMPLE / "robot.json").read_text())
    d["leg_range_mm"] = stroke
    d["leg_offsets"] = [v - offset_shift for v in d["leg_offsets"]]
    out = tmp_path / "robot.json"
    out.write_text(json.dumps(d))
    return out


def _table(tmp_path: Path, shift: float) -> Path:
    """The example's table with every reading ``shift`` mm further."""
    with open(EXAMPLE / "measurements.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        for c in READINGS:
            r[c] = f"{float(r[c]) + shift:.4f}"
    out = tmp_path / "measurements.csv"
    with open(out, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return out


@pytest.mark.parametrize("command", ["calibrate", "diagnose"])
@pytest.mark.parametrize("offsets_follow", [True, False])
def test_readings_300_mm_past_the_stroke_are_refused_with_exit_4(
    tmp_path, capsys, command, offsets_follow
):
    """The campaign's case: readings 300 mm past the stroke, offsets shifted to match (the fit
    would succeed) or not (the offsets' check would have blamed them): refused for the
    stroke, before any fit."""
    table = _table(tmp_path, 300.0)
    robot = _robot(tmp_path, STROKE, 300.0 if offsets_follow else 0.0)
    assert main([command, str(table), "--robot", str(robot)]) == EXIT_DRAWING
    err = capsys.readouterr().err
    assert "legs 1, 2, 3, 4, 5, 6 read beyond the stroke" in err
    assert "leg_range_mm [-5, 115] mm" in err
    # How far: leg 4's top reading, 110.7516 mm, +300 lies 295.75 mm past the end at 115 mm.
    assert "leg 4: 184 of 184 readings beyond the stroke, up to 295.8 mm past its upper" in err
    assert "1. an offset slip" in err and "2. a wrong range" in err
    assert "unit slip" not in err
    assert "offset is" not in err  # the stroke, not the offsets, is named


def test_readings_in_cm_against_a_stroke_in_mm_name_a_unit_slip(tmp_path, capsys):
    table = _table(tmp_path, 0.0)
    d = json.loads((EXAMPLE / "robot.json").read_text())
    d["leg_range_mm"] = [-0.5, 11.5]  # the stroke written in cm
    robot = tmp_path / "robot.json"
    robot.write_text(json.dumps(d))
    assert main(["calibrate", str(table), "--robot", str(robot)]) == EXIT_DRAWING
    err = capsys.readouterr().err
    assert "1. a unit slip: the readings look in 1/10 mm: divide them by 10" in err


def test_readings_within_the_stroke_are_accepted_and_none_said_beyond(tmp_path, capsys):
    table = _table(tmp_path, 0.0)
    robot = _robot(tmp_path, STROKE)
    assert main(["calibrate", str(table), "--robot", str(robot)]) == 0
    assert "beyond the stroke" not in capsys.readouterr().err


def test_beyond_by_less_than_the_noise_is_at_the_end_by_more_is_beyond():
    """A reading past the end by less than the margin (5σ of the stated noise, or the end's own
    margin) is at the end; by more, it is beyond and never said to be at the end."""
    meas = read_measurements(EXAMPLE / "measurements.csv")
    top = float(meas.readings[:, 0].max())  # leg 1's highest reading
    design = load_robot(EXAMPLE / "robot.json")
    sigma = 0.01  # mm: margin max(0.002 × span, 0.05, 5σ) = 0.23 mm for leg 1's 112 mm span
    margin = end_margin_mm(float(np.ptp(meas.readings[:, 0])), sigma)
    assert margin == pytest.approx(0.002 * float(np.ptp(meas.readings[:, 0])))
    inside = design.model_copy(update={"leg_range_mm": [-5.0, top - 0.5 * margin]})
    assert not [f for f in beyond_stroke(meas, inside, sigma) if f.leg == 1]
    at = [e for e in at_limits(meas, inside, sigma).legs if e.leg == 1]
    assert [e.end for e in at] == ["upper"]
    past = design.model_copy(update={"leg_range_mm": [-5.0, top - 2.0 * margin]})
    (found,) = [f for f in beyond_stroke(meas, past, sigma) if f.leg == 1]
    assert found.end == "upper" and found.worst_mm == pytest.approx(2.0 * margin)
    assert int(np.argmax(meas.readings[:, 0])) in found.rows
    assert not any(
        int(np.argmax(meas.readings[:, 0])) in e.rows
        for e in at_limits(meas, past, sigma).legs
        if e.leg == 1
    )


def test_the_advice_never_asks_for_a_stroke_robot_json_gives(tmp_path, capsys):
    """Leg 4's top reading (the table's highest) sits at the stroke's upper end: the poses are
    named, and the advice (text and HTML report) is to leave them out, not to give
    leg_range_mm."""
    table = _table(tmp_path, 0.0)
    meas = read_measurements(table)
    top = float(meas.readings.max())
    robot = _robot(tmp_path, [-5.0, round(top + 0.1, 4)])
    report = tmp_path / "r.html"
    args = ["diagnose", str(table), "--robot", str(robot), "--report", str(report)]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "leg 4 sits at the upper end of its stroke" in out
    assert "leave these poses out with --exclude-at-limits" in out
    html = report.read_text()
    assert "give leg_range_mm" not in out and "give leg_range_mm" not in html
    assert "--exclude-at-limits." in html


def test_the_advice_asks_for_the_stroke_only_when_robot_json_lacks_it():
    from hexcal.diagnosis.limits import advice

    design = load_robot(EXAMPLE / "robot.json")
    assert design.leg_range_mm is None
    assert "give leg_range_mm in robot.json" in advice(design)
    given = design.model_copy(update={"leg_range_mm": STROKE})
    assert "leg_range_mm" not in advice(given) and "--exclude-at-limits" in advice(given)
