"""``hexcal export table``: the compensation table's nodes are hexcal's own readings, its grid is
the documented one, and the interpolation error it states is what interpolating it makes."""

from __future__ import annotations

import csv
import itertools
import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hexcal.app.cli import main
from hexcal.estimate.model_file import leg_model_of, load_model, load_robot
from hexcal.estimate.predict import LegModel
from hexcal.model.iso_tests import iso9283_cube

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "tests" / "data" / "calibrated.json"  # Model 42 + gain
NOMINAL = ROOT / "examples" / "left-hand-sim" / "robot.json"  # its drawing


@pytest.fixture(scope="module")
def table(tmp_path_factory):
    out = tmp_path_factory.mktemp("table")
    args = ["export", "table", str(MODEL), "--out", str(out), "--nominal", str(NOMINAL)]
    assert main([*args, "--points", "3", "--angle-points", "3", "--tilt-deg", "4"]) == 0
    data = json.loads((out / "compensation.json").read_text())
    rows = list(csv.DictReader((out / "compensation.csv").open()))
    return data, rows


def _poses(rows):
    flat = np.array([[float(r[k]) for k in "xyzabc"] for r in rows])
    R = Rotation.from_euler("xyz", flat[:, 3:], degrees=True).as_matrix()
    return flat, flat[:, :3], R


def test_the_grid_is_the_test_cube_and_the_tilts(table):
    data, rows = table
    cube = iso9283_cube(load_model(MODEL))
    axes = data["grid"]["axes"]
    assert axes["x"] == pytest.approx(
        [cube.centre[0] - cube.edge / 2, cube.centre[0], cube.centre[0] + cube.edge / 2]
    )
    assert axes["a"] == pytest.approx([-4.0, 0.0, 4.0])
    assert len(rows) == 3**6 == len(data["readings"]) == len(data["feasible"])
    flat, _, _ = _poses(rows)
    assert np.allclose(flat[:4, 5], [-4.0, 0.0, 4.0, -4.0])  # c fastest, as documented


def test_the_nodes_are_hexcals_readings_and_corrections(table):
    data, rows = table
    _, P, R = _poses(rows)
    model = leg_model_of(load_model(MODEL))
    exact = np.array(
        [model.readings(p[None], r[None], check_limits=False)[0] for p, r in zip(P, R, strict=True)]
    )
    tabled = np.array([[float(r[f"rho{k}"]) for k in range(1, 7)] for r in rows])
    assert np.abs(tabled - exact).max() < 1e-8
    nominal = LegModel(load_robot(NOMINAL)).readings(P, R, check_limits=False)
    corr = np.array([[float(r[f"drho{k}"]) for k in range(1, 7)] for r in rows])
    assert np.abs(corr - (exact - nominal)).max() < 1e-8
    assert np.allclose(np.array(data["corrections"]), corr, atol=1e-8)


def test_the_stated_interpolation_error_is_what_interpolating_makes(table):
    """At each cell's centre multilinear interpolation is the mean of its 64 corners: the error
    stated covers the largest found there, computed here by hand (and random poses inside the
    cells add little to it)."""
    data, _ = table
    axes = [np.array(data["grid"]["axes"][k]) for k in "xyzabc"]
    model = leg_model_of(load_model(MODEL))
    nominal = LegModel(load_robot(NOMINAL))
    grid = np.array(data["readings"]).reshape(*(3,) * 6, 6)
    corr = np.array(data["corrections"]).reshape(*(3,) * 6, 6)
    worst, worst_corr = 0.0, 0.0
    for cell in itertools.product((0, 1), repeat=6):
        idx = np.ix_(*[[i, i + 1] for i in cell])
        centre = np.array([(a[i] + a[i + 1]) / 2 for a, i in zip(axes, cell, strict=True)])
        R = Rotation.from_euler("xyz", centre[3:], degrees=True).as_matrix()[None]
        exact = model.readings(centre[None, :3], R, check_limits=False)[0]
        worst = max(worst, float(np.abs(grid[idx].reshape(-1, 6).mean(0) - exact).max()))
        approx = nominal.readings(centre[None, :3], R, check_limits=False)[0] + corr[idx].reshape(
            -1, 6
        ).mean(0)
        worst_corr = max(worst_corr, float(np.abs(approx - exact).max()))
    stated = data["interpolation_error"]
    assert worst - 1e-12 <= stated["readings"]["reading_max_mm"] <= 2 * worst
    assert worst_corr - 1e-12 <= stated["corrections"]["reading_max_mm"] <= 2 * worst_corr
    assert worst_corr < worst / 20  # the corrections are the table to use
