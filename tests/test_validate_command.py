"""``hexcal validate``: it knows the session a model was fitted on (provenance SHA-256, or the
same poses' values in any copy: re-numbered, re-timed, re-ordered) and then gives no verdict
that the model holds; on a second session — the Jugglebot's other half too, numbered and timed
as the first — it reports each pose's expanded uncertainty and the share inside its 95 %
region."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from hexcal.app.cli import main
from hexcal.io.measurements import Measurements, write_measurements
from hexcal.io.measurements_csv import read_measurements

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "jugglebot"


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


def _renumbered(meas: Measurements, first_id: int, t0: float) -> Measurements:
    """The same poses numbered from ``first_id`` at times t0, t0 + 1, … s."""
    n = len(meas)
    return dataclasses.replace(
        meas, pose_id=np.arange(first_id, first_id + n), t=t0 + np.arange(n, dtype=float)
    )


def test_the_same_poses_in_another_file_are_recognised_by_their_values(fitted, tmp_path, capsys):
    first, second, cal = fitted
    meas = read_measurements(first / "measurements.csv")
    whole, mixed = tmp_path / "copy.csv", tmp_path / "mixed.csv"
    # other bytes, other ids, other times, other order: the same poses
    write_measurements(_renumbered(meas.subset(slice(None, None, -1)), 501, 7.5), whole)
    text = _validate(cal, whole, first / "instruments.json", capsys)
    assert f"all {len(meas)} poses were fitted (the same positions, orientations" in _stats_head(
        text
    )
    # half of the fitted poses among new ones (ids made unique)
    other = read_measurements(second / "measurements.csv")
    half = meas.subset(slice(0, len(meas) // 2))
    rows = [half, dataclasses.replace(other, pose_id=other.pose_id + 10_000)]
    write_measurements(_concat(rows), mixed)
    text = _validate(cal, mixed, first / "instruments.json", capsys)
    n = len(half) + len(other)
    assert f"{len(half)} of these {n} poses were fitted" in _stats_head(text)
    assert "holds" not in text


def test_another_session_with_the_fitted_ids_and_times_is_validated(fitted, tmp_path, capsys):
    first, second, cal = fitted
    meas = read_measurements(first / "measurements.csv")
    other = read_measurements(second / "measurements.csv").subset(slice(0, len(meas)))
    # the second session numbered and timed exactly as the first
    same_ids = dataclasses.replace(
        other, pose_id=meas.pose_id[: len(other)], t=meas.t[: len(other)]
    )
    path = tmp_path / "same_ids.csv"
    write_measurements(same_ids, path)
    out = json.loads(_validate(cal, path, second / "instruments.json", capsys, "--json"))
    assert out["own_session"] is None and out["verdict"] == "none"


def test_an_older_file_without_a_fingerprint_still_knows_its_poses_by_ids(fitted, tmp_path, capsys):
    first, _, cal = fitted
    data = json.loads(cal.read_text())
    del data["calibration"]["fitted_poses"]["fingerprint"]
    del data["calibration"]["uncertainty"]
    data["calibration"]["format_version"] = 2
    old = tmp_path / "old.json"
    old.write_text(json.dumps(data))
    meas = read_measurements(first / "measurements.csv")
    copy = tmp_path / "copy.csv"
    write_measurements(meas.subset(slice(None, None, -1)), copy)
    text = _validate(old, copy, first / "instruments.json", capsys)
    assert f"all {len(meas)} poses were fitted (same pose ids and times" in _stats_head(text)


def test_a_second_session_gets_its_uncertainty_and_coverage(fitted, capsys):
    """The poses' stated 95 % position uncertainty covers their errors on a second session:
    the share covered is within 4σ of 0.95 below (σ the binomial √(0.95·0.05/M) over the M
    poses; the sessions' own spread of coverage is checked by tests/test_rates.py)."""
    _, second, cal = fitted
    out = json.loads(
        _validate(cal, second / "measurements.csv", second / "instruments.json", capsys, "--json")
    )
    assert out["own_session"] is None and out["verdict"] == "none"
    m = out["poses"]
    low = 0.95 - 4 * np.sqrt(0.95 * 0.05 / m)
    assert low <= out["position_coverage_95"] <= 1.0, (out["position_coverage_95"], m, low)
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


@pytest.fixture(scope="module")
def jugglebot_halves(tmp_path_factory):
    """The Jugglebot's 108 real poses split in two halves as recorded — each numbered 1..54 at
    t = 0, 1, … s, as two sessions of the robot's own log would be — and a Model 42 + gain model
    of the first (noise unknown: estimated from its residual)."""
    from hexcal.io.log_import import import_log

    root = tmp_path_factory.mktemp("jugglebot")
    meas = import_log(EXAMPLE / "108_calibration_poses.csv", EXAMPLE / "map.toml")
    half = len(meas) // 2
    first, second = root / "first.csv", root / "second.csv"
    write_measurements(_renumbered(meas.subset(slice(0, half)), 1, 0.0), first)
    write_measurements(_renumbered(meas.subset(slice(half, 2 * half)), 1, 0.0), second)
    cal = root / "cal.json"
    robot = EXAMPLE / "design-robot.json"
    rc = main(["calibrate", str(first), "--robot", str(robot), "--add", "gain", "--out", str(cal)])
    assert rc == 0
    return first, second, cal


def _validate_json(cal, table, capsys) -> dict:
    assert main(["validate", str(cal), str(table), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_the_jugglebot_s_other_half_with_the_same_ids_and_times_is_validated(
    jugglebot_halves, capsys
):
    first, second, cal = jugglebot_halves
    a, b = read_measurements(first), read_measurements(second)
    assert np.array_equal(a.pose_id, b.pose_id) and np.array_equal(a.t, b.t)
    out = _validate_json(cal, second, capsys)
    assert out["own_session"] is None and out["verdict"] is not None


def test_a_renumbered_copy_of_the_jugglebot_s_fitted_half_is_no_validation(
    jugglebot_halves, tmp_path, capsys
):
    first, _, cal = jugglebot_halves
    meas = read_measurements(first)
    copy = tmp_path / "renumbered.csv"
    write_measurements(_renumbered(meas, 1001, 3600.0), copy)
    out = _validate_json(cal, copy, capsys)
    assert out["own_session"] == (
        f"all {len(meas)} poses were fitted (the same positions, orientations and readings as "
        "the model's)"
    )
    assert out["verdict"] is None
    assert main(["validate", str(cal), str(copy)]) == 0
    assert "NOT A VALIDATION" in capsys.readouterr().out


def test_rehome_reports_coverage_and_a_failing_coverage_says_which_term_was_missing(
    jugglebot_halves, capsys
):
    """The Jugglebot's other half: every leg reads about 1 mm short (a re-home) and the model
    lacks something there (45 poses at the stroke's end): the coverage fails, and validate says
    both — the offsets moved (the between-session term was missing) and the verdict."""
    _, second, cal = jugglebot_halves
    assert main(["validate", str(cal), str(second), "--rehome", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["position_coverage_95"] < 0.9
    assert out["rehomed"]["position_coverage_95"] is not None
    assert out["rehomed"]["metrology"]["uncertainty"]["k"] == 2
    missing = " ".join(out["coverage_missing"])
    assert "the robot changed: its offsets moved" in missing
    assert "the model lacks something: the verdict is" in missing
    assert main(["validate", str(cal), str(second), "--rehome"]) == 0
    text = capsys.readouterr().out
    assert "metrology (Model 42 + gain re-homed)" in text
    assert "coverage: the robot changed" in text


def test_fold_in_writes_a_between_session_term_judged_on_another_session(fitted, tmp_path, capsys):
    first, second, cal = fitted
    folded = tmp_path / "folded.json"
    inst = first / "instruments.json"
    args = ["validate", str(cal), str(second / "measurements.csv"), "--instruments", str(inst)]
    assert main([*args, "--fold-in", str(folded)]) == 0
    assert "folded in: a between-session term of" in capsys.readouterr().out
    u = json.loads(folded.read_text())["calibration"]["uncertainty"]
    assert u["between_session_dof"] == 6 and u["between_session_poses"] > 0
    assert u["between_session_mm"] >= 0 and "measurements.csv" in u["between_session_source"]
    # a third session: the statement now names the term and its contribution
    third = tmp_path / "third"
    assert main(["simulate", "--out", str(third), "--seed", "8", "--pose-seed", "11"]) == 0
    capsys.readouterr()
    assert main(["validate", str(folded), str(third / "measurements.csv"), "--json"]) == 0
    unc = json.loads(capsys.readouterr().out)["metrology"]["uncertainty"]
    assert unc["between_session_mm"] == u["between_session_mm"]
    assert [c["with"].split(" (")[0] for c in unc["contributions"]] == [
        "the parameters and the readings",
        "+ model inadequacy",
        "+ between sessions",
    ]
    # never from the session the model was fitted on
    assert (
        main([*args[:2], str(first / "measurements.csv"), "--fold-in", str(tmp_path / "x.json")])
        == 2
    )
    assert "needs poses the model was not fitted on" in capsys.readouterr().err


def test_the_jugglebot_s_term_from_one_quarter_covers_the_last_quarter(
    jugglebot_halves, tmp_path, capsys
):
    """docs/metrology.md's figures: poses 55–81 folded in as a second session, the statement
    judged on poses 82–108 only — 15 % of the positions covered without the between-session
    term, all with it (a 1.4 mm term: the model holds little on another part of the day)."""
    _, second, cal = jugglebot_halves
    meas = read_measurements(second)
    q3, q4 = tmp_path / "q3.csv", tmp_path / "q4.csv"
    write_measurements(meas.subset(slice(0, 27)), q3)
    write_measurements(meas.subset(slice(27, None)), q4)
    folded = tmp_path / "folded.json"
    assert main(["validate", str(cal), str(q3), "--fold-in", str(folded)]) == 0
    capsys.readouterr()
    unc = _validate_json(folded, q4, capsys)["metrology"]["uncertainty"]
    plain, inadequacy, both = (c["position_coverage_95"] for c in unc["contributions"])
    assert plain < 0.3 and inadequacy == plain  # no inadequacy term: the noise was estimated
    assert both >= 0.95 and 1.0 < unc["between_session_mm"] < 2.0


def test_without_an_instruments_file_validate_calls_every_floor_estimated(jugglebot_halves, capsys):
    _, second, cal = jugglebot_halves
    assert main(["validate", str(cal), str(second)]) == 0
    text = capsys.readouterr().out
    assert "instruments' own noise" not in text and "instruments allow" not in text
    floor_lines = [line for line in text.splitlines() if "floor" in line]
    assert floor_lines and all("estimated" in line for line in floor_lines), floor_lines
