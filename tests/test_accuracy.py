"""Pose accuracy against the truth of simulation: the floor the noise alone gives (analytic,
checked by Monte-Carlo), and a calibration validated on a second session of the same robot
(``hexcal calibrate --add gain --out`` then ``hexcal validate``)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from statcheck import FLOOR_K, heldout_sd_rel_bound, pose_floor_limit

from hexcal.app.cli import main
from hexcal.estimate.accuracy import pose_errors, pose_floor
from hexcal.estimate.predict import LegModel
from hexcal.model.noise import NoiseSigmas
from hexcal.sim.inject import effect_hook, realistic_values
from hexcal.sim.robots import left_hand
from hexcal.sim.session_sim import SessionPlan, perturbed_truth, simulate_session, write_session_dir

SEED = 11
PLAN = SessionPlan()


def _truth():
    """The simulated robot of ``hexcal simulate --seed SEED --effect gain`` and its model."""
    design = left_hand()
    rng = np.random.default_rng(SEED)
    truth = perturbed_truth(design, rng, PLAN)
    values = realistic_values("gain", rng, truth)
    return design, truth, values


def _sigmas() -> NoiseSigmas:
    n = PLAN.noise
    return NoiseSigmas(n.sigma_position_mm, n.sigma_orientation_rad, n.sigma_reading_mm)


@pytest.fixture(scope="module")
def monte_carlo_floor() -> dict:
    """The position and orientation RMS of the TRUE model's pose error over 40 sessions of the
    robot: what the instruments' noise alone gives (no model error at all)."""
    _, truth, values = _truth()
    hook = effect_hook("gain", values, truth)
    model = LegModel(truth, ("gain",), values)
    pos, ang, analytic = [], [], []
    for pose_seed in range(100, 140):
        meas, _ = simulate_session(left_hand(), pose_seed, PLAN, effects=[hook], truth=truth)
        e = pose_errors(model, meas)
        assert e.closed.all()
        pos.append(np.mean(e.position_mm**2))
        ang.append(np.mean(e.orientation_deg**2))
        analytic.append(pose_floor(truth.a, truth.b, meas, _sigmas()))
    return {
        "position_mm": float(np.sqrt(np.mean(pos))),
        # the standard error of that RMS, from the sessions' spread (poses within a session
        # share its draws: the sessions are the independent samples)
        "position_se": float(np.std(np.sqrt(pos), ddof=1) / np.sqrt(len(pos))),
        "orientation_deg": float(np.sqrt(np.mean(ang))),
        "orientation_se": float(np.std(np.sqrt(ang), ddof=1) / np.sqrt(len(ang))),
        "analytic_position_mm": float(np.mean([a[0] for a in analytic])),
        "analytic_orientation_deg": float(np.mean([a[1] for a in analytic])),
    }


def test_the_analytic_pose_floor_matches_monte_carlo(monte_carlo_floor):
    """The propagated floor (readings' noise through the kinematics plus the tracker's own)
    equals the true model's RMS pose error over 40 noisy sessions, within 4σ of the
    Monte-Carlo's own uncertainty (σ: the standard error from the 40 sessions' spread, ≈ 1 %
    for 40 × 184 poses)."""
    mc = monte_carlo_floor
    assert abs(mc["analytic_position_mm"] - mc["position_mm"]) < 4 * mc["position_se"], mc
    assert abs(mc["analytic_orientation_deg"] - mc["orientation_deg"]) < 4 * mc["orientation_se"], (
        mc
    )


def test_a_calibration_validated_on_a_second_session_reaches_the_floor(
    tmp_path, capsys, monte_carlo_floor
):
    """``hexcal calibrate --add gain --out cal.json`` on one session, ``hexcal validate
    cal.json`` on a second session of the same robot (same truth, new poses and noise): the
    position RMS is at the floor the noise alone gives (Monte-Carlo above): above it by no more
    than 3σ of a correct model's (tests/statcheck.py: σ ≤ 1/√(2M) over M poses, χ² one dof a
    pose), below it by no more than 3σ; and at least 5× below the drawing's."""
    fit_dir, val_dir = tmp_path / "fit", tmp_path / "val"
    write_session_dir(fit_dir, left_hand(), SEED, PLAN, "gain")
    write_session_dir(val_dir, left_hand(), SEED, PLAN, "gain", pose_seed=SEED + 1000)
    cal = tmp_path / "cal.json"
    args = [
        "calibrate",
        str(fit_dir / "measurements.csv"),
        "--robot",
        str(fit_dir / "robot.json"),
        "--instruments",
        str(fit_dir / "instruments.json"),
        "--add",
        "gain",
        "--out",
        str(cal),
    ]
    assert main(args) == 0
    capsys.readouterr()

    def validate(model) -> dict:
        assert main(["validate", str(model), str(val_dir / "measurements.csv"), "--json"]) == 0
        return json.loads(capsys.readouterr().out)

    v = validate(cal)
    floor = monte_carlo_floor["position_mm"]
    assert v["model"] == "Model 42 + gain"
    low = floor * (1 - FLOOR_K * heldout_sd_rel_bound(v["poses"]))
    high = pose_floor_limit(floor, v["poses"], 48)  # Model 42 + gain
    assert low <= v["position_rms_mm"] <= high, (v["position_rms_mm"], low, high)
    assert v["verdict"] == "none"
    for key in ("position_p95_mm", "orientation_rms_deg", "leg_rms_mm", "noise_floor_mm"):
        assert np.isfinite(v[key])
    design = validate(fit_dir / "robot.json")
    assert design["position_rms_mm"] > 5 * v["position_rms_mm"]
    assert design["verdict"] != "none"


def _fitted_and_second_session(tmp_path, effect: str):
    """(calibrated.json with ``effect`` added, the --instruments arguments, a second session's
    table) of the simulated robot hiding ``effect``: another day's poses, the same robot."""
    from hexcal.io.measurements_csv import read_measurements

    fit_dir, val_dir = tmp_path / "fit", tmp_path / "val"
    write_session_dir(fit_dir, left_hand(), SEED, PLAN, effect)
    write_session_dir(val_dir, left_hand(), SEED, PLAN, effect, pose_seed=SEED + 2000)
    cal = tmp_path / "cal.json"
    args = ["calibrate", str(fit_dir / "measurements.csv"), "--robot", str(fit_dir / "robot.json")]
    inst = ["--instruments", str(fit_dir / "instruments.json")]
    assert main([*args, *inst, "--add", effect, "--out", str(cal)]) == 0
    return cal, inst, read_measurements(val_dir / "measurements.csv")


def test_validate_names_a_moved_zero_and_rehomes(tmp_path, capsys):
    """Another day's session after power-up: legs 3 and 5 read 0.75 and 1.7 mm short (their
    encoders homed elsewhere), every other leg at its noise. validate says it is a constant
    shift of those two legs; --rehome re-estimates the offsets alone and the pose error is back
    at the floor."""
    import dataclasses

    from hexcal.io.measurements import write_measurements

    cal, inst, meas = _fitted_and_second_session(tmp_path, "gain")
    rho = meas.readings.copy()
    rho[:, 2] -= 0.75
    rho[:, 4] -= 1.7
    table = tmp_path / "rehomed.csv"
    write_measurements(dataclasses.replace(meas, readings=rho), table)
    capsys.readouterr()
    assert main(["validate", str(cal), str(table), *inst, "--rehome", "--json"]) == 0
    v = json.loads(capsys.readouterr().out)
    assert v["shifted_legs"] == [3, 5] and v["verdict"] == "offset"
    assert v["position_rms_mm"] > 20 * v["position_floor_mm"]
    r = v["rehomed"]
    assert np.allclose(r["offset_shift_mm"], [0, 0, 0.75, 0, 1.7, 0], atol=0.01)
    # back at the floor: within 3σ (σ from the pose count, tests/statcheck.py); Model 42 + gain
    limit = pose_floor_limit(r["position_floor_mm"], v["poses"], 48)
    assert r["verdict"] == "none" and r["position_rms_mm"] < limit, (r, limit)


def test_validate_leaves_out_the_poses_whose_backlash_side_is_unknown(tmp_path, capsys):
    """A real robot comes to a session's first pose from a move made before the session: which
    side of its play each leg rests on is unknown there (the simulator takes it as the middle,
    the mock rig and a real robot do not). Here three of the first pose's legs read 0.1 mm long, as
    after extending into it with 0.2 mm of play: validate leaves that pose out of its verdict, names it
    and why, and the model holds on the rest. The same shift on a pose whose legs had moved is
    judged: the model does not hold."""
    import dataclasses

    from hexcal.io.measurements import write_measurements

    cal, inst, meas = _fitted_and_second_session(tmp_path, "backlash")

    def validate(row: int, legs) -> dict:
        rho = meas.readings.copy()
        rho[row, legs] += 0.1
        table = tmp_path / f"shifted{row}.csv"
        write_measurements(dataclasses.replace(meas, readings=rho), table)
        capsys.readouterr()
        assert main(["validate", str(cal), str(table), *inst, "--json"]) == 0
        return json.loads(capsys.readouterr().out)

    first = validate(0, [0, 2, 4])  # legs 1, 3 and 5 extended into it
    assert first["poses_left_out"] == [int(meas.pose_id[0])]
    assert first["verdict"] == "none" and first["chi2_per_dof"] < 1.3
    (note,) = [n for n in first["notes"] if "left out of the verdict" in n]
    assert "backlash: a leg had not moved yet" in note
    later = validate(len(meas) // 2, [0, 2, 4])
    assert later["poses_left_out"] == [int(meas.pose_id[0])]
    assert later["verdict"] != "none"


def test_an_estimated_floor_is_capped_at_the_best_held_out_residual():
    from hexcal.estimate.accuracy import floor_cap

    assert floor_cap(0.439, [0.3615, 0.3594, float("nan")]) == pytest.approx(0.3594 / 0.439)
    assert floor_cap(0.300, [0.3615, 0.3594]) == 1.0  # already below: left as it is
    assert floor_cap(0.439, []) == 1.0 and floor_cap(0.0, [0.3]) == 1.0
