"""``hexcal validate``: it knows the session a model was fitted on (provenance SHA-256, or the
same pose ids and times) and then gives no verdict that the model holds; on a second session it
reports each pose's expanded uncertainty and the share inside its 95 % region."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from hexcal.app.cli import main
from hexcal.io.measurements import Measurements, write_measurements
from hexcal.io.measurements_csv import read_measurements


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """(calibration session, second session, calibrated.json) of one simulated robot."""
    root = tmp_path_factory.mktemp("validate")
    first, second = root / "first", root / "second"
    assert main(["simulate", "--out", str(first), "--seed", "8"]) == 0
    assert main(["simulate", "--out", str(second), "--seed", "8", "--pose-seed", "9"]) == 0
    cal = root / "cal.json"
    rc = main(
        [
            "calibrate",
            str(first / "measurements.csv"),
            "--robot",
            str(first / "robot.json"),
            "--instruments",
            str(first / "instruments.json"),
            "--out",
            str(cal),
        ]
    )
    assert rc == 0
    return first, second, cal


def _stats_head(text: str) -> str:
    """The first line under the statistics' heading (the plain words come before it)."""
    return text.split("\nStatistics\n")[1].splitlines()[1]


def _validate(cal, table, inst, capsys, *more):
    args = ["validate", str(cal), str(table), "--instruments", str(inst), *more]
    assert main(args) == 0
    return capsys.readouterr().out


def test_the_session_it_was_fitted_on_is_named_and_no_holds_verdict(fitted, capsys):
    first, _, cal = fitted
    text = _validate(cal, first / "measurements.csv", first / "instruments.json", capsys)
    assert text.startswith("This is not a validation")  # in plain words first
    head = _stats_head(text)
    assert "NOT A VALIDATION" in head and "SHA-256 is in the provenance" in head
    assert "poses it was not fitted on" not in text
    assert "holds" not in text and "verdict: not given" in text
    out = json.loads(
        _validate(cal, first / "measurements.csv", first / "instruments.json", capsys, "--json")
    )
    assert out["own_session"] and out["verdict"] is None


def test_the_same_poses_in_another_file_are_recognised_by_ids_and_times(fitted, tmp_path, capsys):
    first, second, cal = fitted
    meas = read_measurements(first / "measurements.csv")
    whole, mixed = tmp_path / "copy.csv", tmp_path / "mixed.csv"
    write_measurements(meas.subset(slice(None, None, -1)), whole)  # other bytes, same poses
    text = _validate(cal, whole, first / "instruments.json", capsys)
    assert f"all {len(meas)} poses were fitted (same pose ids and times" in _stats_head(text)
    # half of the fitted poses among new ones (ids made unique)
    other = read_measurements(second / "measurements.csv")
    half = meas.subset(slice(0, len(meas) // 2))
    rows = [half, dataclasses.replace(other, pose_id=other.pose_id + 10_000)]
    write_measurements(_concat(rows), mixed)
    text = _validate(cal, mixed, first / "instruments.json", capsys)
    n = len(half) + len(other)
    assert f"{len(half)} of these {n} poses were fitted" in _stats_head(text)
    assert "holds" not in text


def test_a_second_session_gets_its_uncertainty_and_coverage(fitted, capsys):
    _, second, cal = fitted
    out = json.loads(
        _validate(cal, second / "measurements.csv", second / "instruments.json", capsys, "--json")
    )
    assert out["own_session"] is None and out["verdict"] == "none"
    assert 0.85 <= out["position_coverage_95"] <= 1.0
    u = out["metrology"]["uncertainty"]
    assert u["k"] == 2 and "parameters" in u["source"]
    assert len(u["poses"]) == out["poses"] and all(p["U_position_mm"] > 0 for p in u["poses"])
    text = _validate(cal, second / "measurements.csv", second / "instruments.json", capsys)
    assert "poses it was not fitted on" in _stats_head(text)
    assert text.startswith("The model holds on this session")
    assert "holds on these poses" in text and "uncertainty (GUM, k = 2" in text


def _concat(parts: list[Measurements]) -> Measurements:
    return Measurements.from_arrays(
        np.concatenate([p.position for p in parts]),
        np.concatenate([p.quaternion for p in parts]),
        np.concatenate([p.readings for p in parts]),
        leg=np.concatenate([p.leg for p in parts]),
        constraint=np.concatenate([p.constraint for p in parts]),
        step=np.concatenate([p.step for p in parts]),
        t=np.concatenate([p.t for p in parts]),
        pose_id=np.concatenate([p.pose_id for p in parts]),
        temperature=np.concatenate([p.temperature for p in parts]),
    )
