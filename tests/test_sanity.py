"""A calibration checked against the drawing, gross outlier poses, fits that do not converge,
and the command line's one error path: user slips are named, never calibrated silently."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from hexcal.app.cli import (
    EXIT_DRAWING,
    EXIT_INPUT,
    EXIT_INTERNAL,
    EXIT_REFUSED,
    error_message,
    main,
)
from hexcal.estimate import refine as refine_module
from hexcal.estimate.model_file import load_robot
from hexcal.estimate.sanity import check_against_drawing, gross_outliers
from hexcal.sim.inject import effect_hook, realistic_values
from hexcal.sim.robots import left_hand
from hexcal.sim.session_sim import SessionPlan, perturbed_truth, simulate_session

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "left-hand-sim"


def _example_args(table: Path) -> list[str]:
    return [
        str(table),
        "--robot",
        str(EXAMPLE / "robot.json"),
        "--instruments",
        str(EXAMPLE / "instruments.json"),
    ]


def _rewrite(tmp_path: Path, name: str, edit) -> Path:
    rows = list(csv.reader((EXAMPLE / "measurements.csv").open()))
    edit(rows)
    out = tmp_path / name
    with out.open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    return out


def test_swapped_encoder_columns_are_flagged_and_not_written(tmp_path, capsys):
    """rho1 ↔ rho2 in the header: the fit is excellent (legs 1 and 2 simply exchanged), and
    only the drawing tells: exit 4, the two legs named with the likely causes, no --out."""

    def swap(rows):
        h = rows[0]
        i, j = h.index("rho1"), h.index("rho2")
        h[i], h[j] = h[j], h[i]

    table = _rewrite(tmp_path, "swapped.csv", swap)
    out = tmp_path / "cal.json"
    assert main(["calibrate", *_example_args(table), "--out", str(out)]) == EXIT_DRAWING
    err = capsys.readouterr().err
    assert "legs 1 and 2 look swapped" in err and "rho1 ↔ rho2" in err
    assert f"{out} was not written" in err and not out.exists()
    assert main(["diagnose", *_example_args(table)]) == EXIT_DRAWING
    assert "legs 1 and 2 look swapped" in capsys.readouterr().err
    # The user who knows better can say so.
    assert main(["calibrate", *_example_args(table), "--no-drawing-check"]) == 0


def _moved(points: np.ndarray, seed: int) -> np.ndarray:
    """The points in another frame: a tracker not registered to the base, a tool body off the
    platform's origin."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    return Rotation.random(random_state=seed).apply(points) + rng.uniform(-500, 500, 3)


def test_the_drawing_check_ignores_the_trackers_frame():
    """Fitted points in any frame (the tracker's, the tool's) match their own drawing; legs
    swapped in that frame are still found."""
    design = load_robot(EXAMPLE / "robot.json")
    assert check_against_drawing(_moved(design.a, 1), _moved(design.b, 2), design) == []
    swapped = design.a[[1, 0, 2, 3, 4, 5]]
    found = check_against_drawing(
        _moved(swapped, 3), _moved(design.b[[1, 0, 2, 3, 4, 5]], 4), design
    )
    assert [f.kind for f in found] == ["swapped"] and found[0].legs == (1, 2)


def test_a_leg_off_its_drawing_is_named(tmp_path):
    design = load_robot(EXAMPLE / "robot.json")
    a, b = design.a.copy(), design.b.copy()
    a[3] += [0.0, 0.0, 40.0]  # leg 4's base point 40 mm off: a wrong sign, scale or drawing
    found = check_against_drawing(_moved(a, 5), _moved(b, 6), design)
    assert [f.legs for f in found] == [(4,)] and found[0].kind == "far"
    assert "leg 4's fitted points lie 40.0 mm (base)" in found[0].text


def test_one_typo_is_named_as_an_outlier_pose(tmp_path, capsys):
    """x = −496 instead of its value in one pose: named with its id, step and time, before any
    fit (exit 2); leaving it out calibrates."""

    def typo(rows):
        rows[40][rows[0].index("x")] = "-496"

    table = _rewrite(tmp_path, "typo.csv", typo)
    assert main(["calibrate", *_example_args(table)]) == EXIT_INPUT
    err = capsys.readouterr().err
    assert "pose 40 (step leg2-direction+length, t 536.337 s)" in err
    assert "--exclude-poses 40" in err
    assert main(["diagnose", *_example_args(table)]) == EXIT_INPUT
    capsys.readouterr()
    assert main(["calibrate", *_example_args(table), "--exclude-poses", "40", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["chi2_per_dof"] < 1.5


@pytest.mark.parametrize("effect", ["gain", "backlash", "thermal", "compliance", "leadscrew"])
def test_no_outlier_is_called_in_sessions_with_a_real_effect(effect):
    """The outlier screen must not mistake an effect (at three times its realistic size) or the
    drawing's own errors for outliers: 10 sessions each."""
    design = left_hand().model_copy(update={"platform_mass_kg": 30.0})
    plan = SessionPlan(temperature_rise_k=5.0)
    for seed in range(10):
        rng = np.random.default_rng(seed)
        truth = perturbed_truth(design, rng, plan)
        hook = effect_hook(effect, 3 * realistic_values(effect, rng, truth), truth)
        meas, _ = simulate_session(design, seed, plan, effects=[hook], truth=truth)
        assert gross_outliers(meas, design) == []


def test_a_fit_that_does_not_converge_names_the_poses(monkeypatch, capsys):
    """A refinement that exhausts its evaluations stops (exit 3) and names the poses with the
    largest residual; it is never reported as a result."""
    monkeypatch.setattr(refine_module, "MAX_NFEV", 1)
    assert main(["calibrate", *_example_args(EXAMPLE / "measurements.csv")]) == EXIT_REFUSED
    err = capsys.readouterr().err
    assert "did not converge" in err and "the poses pulling it: pose " in err


def test_errors_reach_the_user_as_words_and_an_exit_status():
    """One error path: library exceptions are put in words, never their raw text."""
    code, msg = error_message(np.linalg.LinAlgError("Matrix is not positive definite"))
    assert code == EXIT_REFUSED and "Matrix is not positive definite" not in msg
    assert "do not determine the geometry" in msg
    code, msg = error_message(RecursionError("maximum recursion depth exceeded"))
    assert code == EXIT_INPUT and "nested" in msg
    code, msg = error_message(MemoryError())
    assert code == EXIT_INPUT and "out of memory" in msg and "too long for this machine" in msg
    code, msg = error_message(UnicodeDecodeError("utf-8", b"\x96", 0, 1, "invalid start byte"))
    assert code == EXIT_INPUT and "codec" not in msg and "UTF-8" in msg
    code, msg = error_message(KeyError("x"))
    assert code == EXIT_INTERNAL and "please report it" in msg


@pytest.mark.parametrize(
    "argv, says",
    [
        (["demo", "--window-s", "inf"], "'inf' is not finite"),
        (["demo", "--poses-per-step", "-1"], "-1 is outside [1, 10000]"),
        (["run", "--mock", "--window-s", "0"], "0 is outside (0, 60]"),
        (["simulate", "--out", "x", "--n-free", "1e9"], "'1e9' is not an integer"),
        (["simulate", "--out", "x", "--sigma-p-mm", "nan"], "'nan' is not finite"),
        (["study", "--trials", "0"], "0 is outside [1, 100000]"),
    ],
)
def test_options_are_finite_and_in_range(argv, says, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    assert says in capsys.readouterr().err


def test_outputs_never_replace_an_existing_file_without_force(tmp_path, capsys):
    out = tmp_path / "sim"
    assert main(["simulate", "--out", str(out)]) == 0
    before = (out / "measurements.csv").read_text()
    assert main(["simulate", "--out", str(out), "--seed", "2"]) == EXIT_INPUT
    assert "pass --force" in capsys.readouterr().err
    assert (out / "measurements.csv").read_text() == before
    assert main(["simulate", "--out", str(out), "--seed", "2", "--force"]) == 0
    assert (out / "measurements.csv").read_text() != before
