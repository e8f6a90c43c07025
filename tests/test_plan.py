"""The planner (:mod:`hexcal.diagnosis.plan`): every planned pose reachable, and planned poses
separating two look-alikes better than random ones. The rates over 50 sessions per pair are
measured by benchmarks/plan_rates.py."""

from __future__ import annotations

import numpy as np
import pytest

from hexcal.diagnosis.plan import GEOMETRY, plan_poses
from hexcal.diagnosis.plan_pool import reachable
from hexcal.estimate.effect_fit import Problem, fit_model, fitted_robot
from hexcal.estimate.predict import LegModel, Poses
from hexcal.model.noise import NoiseSigmas
from hexcal.sim import verdict_cases as vc
from hexcal.sim.inject import effect_hook, realistic_values
from hexcal.sim.robots import left_hand
from hexcal.sim.session_sim import SessionPlan, perturbed_truth, simulate_session


def _session(seed: int, leg_range=None, joint_limit=None):
    design = left_hand()
    rng = np.random.default_rng(seed)
    plan = SessionPlan(temperature_rise_k=5.0, n_free=20)
    truth = perturbed_truth(design, rng, plan)
    hook = effect_hook("thermal", realistic_values("thermal", rng, truth), truth)
    meas, _ = simulate_session(design, seed, plan, effects=[hook], truth=truth)
    # The limits bind the plan, not the session recorded before them.
    limited = design.model_copy(update={"leg_range_mm": leg_range, "joint_limit_deg": joint_limit})
    return Problem.build(meas, limited, NoiseSigmas.from_instruments(vc.INSTRUMENTS))


def test_every_planned_pose_is_reachable_by_the_inverse_kinematics_strokes_and_joints():
    """Limits that bind: a stroke that cuts the session's readings at their 10th and 90th
    percentiles and joints within 20°; each planned pose's readings (the inverse kinematics) are within the stroke,
    its joints within their limit, and the readings give back the pose (forward kinematics)."""
    rho0 = _session(3).meas.readings
    stroke = [float(np.percentile(rho0, 10)), float(np.percentile(rho0, 90))]
    problem = _session(3, leg_range=stroke, joint_limit=20.0)
    plan = plan_poses(problem, ("offset",), 10, separate=("thermal", "drift"), n_candidates=600)
    robot = fitted_robot(problem.design, fit_model(problem, ("offset",), False).refinement)
    model = LegModel(robot)
    P, R = plan.meas.position, plan.meas.rotations.as_matrix()
    rho = model.readings(P, R, check_limits=True)  # raises beyond a stroke or a joint's limit
    lo, hi = robot.leg_range_mm
    assert np.all((rho >= lo) & (rho <= hi))
    base, plat = model.joint_angles(Poses(P, R))
    assert np.maximum(base, plat).max() <= 20.0
    assert reachable(robot, P, R).all()
    back = model.poses(rho, guess=Poses(P, R))
    np.testing.assert_allclose(back.position, P, atol=1e-6)
    np.testing.assert_allclose(plan.meas.readings, rho, atol=1e-3)  # the table's 4 decimals
    _check_schedule(problem, plan)


def _check_schedule(problem, plan, lab=None):
    """The plan's time and temperature columns: the first pose ``plan.wait`` + one pose's
    pace after the session's last, then one every pace (the session's median); one
    temperature held — the session's last, or within the lab's range ``lab`` and no farther
    from the last than the session's own rate (its range over its span) reaches by then."""
    meas = problem.meas
    dt = max(float(np.median(np.diff(meas.t))), 1.0)
    t = plan.meas.t
    assert plan.wait >= 0
    np.testing.assert_allclose(t[0], meas.t[-1] + plan.wait + dt, atol=1e-3)
    np.testing.assert_allclose(np.diff(t), dt, atol=1e-3)
    temp = plan.meas.temperature
    assert np.ptp(temp) == 0
    if lab is None:
        assert temp[0] == meas.temperature[-1]
        return
    rate = np.ptp(meas.temperature) / np.ptp(meas.t)
    assert lab[0] <= temp[0] <= lab[1]
    assert abs(temp[0] - meas.temperature[-1]) <= rate * (plan.wait + dt) + 0.01


def test_a_drift_pair_is_planned_after_a_wait_and_the_simulator_records_when_and_where_planned():
    """Thermal against drift: poses at the session's last temperature tell them apart only
    through time (the drift going on while the temperature holds), so the plan waits before
    them, at most the session's own span; where the lab can hold the rig anywhere in the
    session's range, it chooses a temperature too, reachable by then at the session's own
    rate. The look-alike's simulator records the plan's poses at its times and temperatures
    (the thermometer's 0.05 K jitter: 0.25 K is 5σ)."""
    from hexcal.diagnosis.plan import When
    from hexcal.sim.plan_cases import case

    c = case("thermal vs drift", 3, 0.5)  # the session alone far from deciding
    problem = Problem.build(c.meas, c.design, NoiseSigmas.from_instruments(c.instruments))
    span = float(np.ptp(c.meas.t))
    held = plan_poses(problem, ("offset",), 8, separate=c.pair, n_candidates=300)
    assert 0 < held.wait <= span + 1e-6
    _check_schedule(problem, held)
    lab = (float(c.meas.temperature.min()), float(c.meas.temperature.max()))
    chosen = plan_poses(
        problem, ("offset",), 8, separate=c.pair, n_candidates=300, when=When(temperatures=lab)
    )
    _check_schedule(problem, chosen, lab)
    assert chosen.planned >= held.planned * 0.9  # a choice more, at least as good (a 10 % slack:
    # the schedule is chosen on a sample of the candidates, the poses then on all of them)
    asked = plan_poses(
        problem, ("offset",), 4, separate=c.pair, n_candidates=300, when=When(60.0, None, 21.5)
    )
    assert asked.wait == 60.0 and set(asked.meas.temperature) == {21.5}
    P, R = chosen.meas.position, chosen.meas.rotations.as_matrix()
    got = c.record(P, R, chosen.meas.t, 1, chosen.meas.temperature)
    new = got.step == "plan"
    np.testing.assert_array_equal(got.t[new], chosen.meas.t)
    assert np.abs(got.temperature[new] - chosen.meas.temperature).max() <= 0.25


def test_planned_poses_separate_better_than_random_ones_and_geometry_counts_one_way():
    problem = _session(5)
    plan = plan_poses(problem, ("offset",), 8, separate=("thermal", "drift"), n_candidates=600)
    assert plan.planned > plan.random > plan.before
    assert plan.match is None or plan.match > 8
    nested = plan_poses(problem, ("offset",), 4, separate=(GEOMETRY, "drift"), n_candidates=300)
    assert set(nested.expected) == {"drift"}


def test_a_hypothesis_already_in_the_model_is_refused():
    with pytest.raises(ValueError, match="already in the model"):
        plan_poses(_session(6), ("offset", "thermal"), 4, separate=("thermal", "drift"))


def test_the_diagnosis_offers_plans_with_the_command_that_makes_them():
    """A look-alike named with the verdict and a candidate the poses cannot resolve are each
    offered a plan: how many poses would decide, and ``hexcal plan``'s arguments."""
    from types import SimpleNamespace

    from hexcal.diagnosis.plan_offer import MAX_OFFER, offers
    from hexcal.diagnosis.scoring import Candidate
    from hexcal.diagnosis.text import plan_lines

    problem = _session(5)
    fit = fit_model(problem, ("offset",), False)
    stuck = Candidate("ujoint", 0.0, identifiable=False, available=True)
    found = offers(problem, fit, "thermal", ["drift"], [stuck])
    # ujoint is offered only when its columns, the unresolved ones too, would remove more than
    # the look-alike margin at this fit: whether they do is the score test's.
    from hexcal.diagnosis.score import score_columns

    whole = score_columns(problem, fit, "ujoint").score(np.ones(6, bool))
    expected = [("separate", ("thermal", "drift"))] + (
        [("resolve", ("ujoint",))] if whole >= 10 else []
    )
    assert [(o.kind, o.hypotheses) for o in found] == expected
    for o in found:
        assert o.poses is None or 1 <= o.poses <= MAX_OFFER
    assert found[0].args()[:3] == ["--separate", "thermal", "drift"]
    text = plan_lines(SimpleNamespace(plans=found), "hexcal plan s.csv --robot r.json")  # type: ignore[arg-type]
    assert "hexcal plan s.csv --robot r.json --separate thermal drift --poses" in text[1]


def test_a_separation_decides_when_two_sd_short_of_its_mean_it_pays_its_parameters_and_margin():
    """The expected Δχ², less 2 sd, against what the verdict asks: dp·ln n in ΔBIC and the
    look-alike margin; against the model alone, very strong evidence (dp·ln n + 10)."""
    from hexcal.diagnosis.selection import ALIKE_DCHI2, BIC_STRONG, separates

    n, sd = 1000, 10.0
    cost = 5 * np.log(n)  # gain's six parameters against compliance's one
    assert separates(cost + 2 * sd + 0.1, sd, 5, n, nested=False)
    assert not separates(cost + 2 * sd - 0.1, sd, 5, n, nested=False)
    # Fewer parameters than the other: the look-alike margin is what counts.
    assert separates(ALIKE_DCHI2 + 2 * sd + 0.1, sd, -2, n, nested=False)
    assert not separates(ALIKE_DCHI2 + 2 * sd - 0.1, sd, -2, n, nested=False)
    strong = 6 * np.log(n) - BIC_STRONG
    assert separates(strong + 2 * sd + 0.1, sd, 6, n, nested=True)
    assert not separates(strong + 2 * sd - 0.1, sd, 6, n, nested=True)


@pytest.mark.parametrize("resolved", [True, False])
def test_the_predicted_delta_chi2_is_unbiased_and_its_sd_the_realised_spread_over_sessions(
    resolved,
):
    """A linear model, known: common columns X, the true model's own A (its θ drawn once),
    the other's B, partly alike; 60 session rows, 30 new. 3000 sessions redrawn (the session's
    noise and the new rows' alike), Δχ² = χ²_B − χ²_A refitted on every row each time, less
    :func:`predicted_delta_chi2`'s mean of that session: d. Its mean is 0 within 4 standard
    errors (σ: d's own sample sd / √3000). The predicted variance is d's: mean sd² within 4
    standard errors of var d (σ: the sample sd of (d − d̄)² / √3000) where A is resolved by
    the session; where it is not (its session columns 5 times smaller), the sd estimated from
    ŷ is clipped at 0 now and then and so errs large, never small (mean sd² ≥ var d − 4σ)."""
    from hexcal.diagnosis.selection import predicted_delta_chi2

    rng = np.random.default_rng(0 if not resolved else 1)
    m, n, px, pa, pb = 60, 30, 4, 4, 3
    X = rng.normal(size=(m + n, px))
    A = rng.normal(size=(m + n, pa)) + 0.5 * X[:, :pa]
    if not resolved:
        A[:m] *= 0.2
    B = 0.7 * A[:, :1] @ np.ones((1, pb)) + rng.normal(size=(m + n, pb))
    za, zb = np.hstack([X, A]), np.hstack([X, B])
    truth = np.concatenate([rng.normal(size=px), (1.0 if resolved else 0.3) * rng.normal(size=pa)])

    def chi2(z, y):
        return float(np.sum((y - z @ np.linalg.lstsq(z, y, rcond=None)[0]) ** 2))

    draws = 3000
    d, var = np.empty(draws), np.empty(draws)
    for k in range(draws):
        ys = za[:m] @ truth + rng.normal(size=m)
        y = np.concatenate([ys, za[m:] @ truth + rng.normal(size=n)])
        mean, sd = predicted_delta_chi2(za, zb, ys)
        d[k], var[k] = chi2(zb, y) - chi2(za, y) - mean, sd**2
    assert abs(d.mean()) <= 4 * d.std(ddof=1) / np.sqrt(draws)
    sq = (d - d.mean()) ** 2
    se = sq.std(ddof=1) / np.sqrt(draws)
    if resolved:
        assert abs(var.mean() - sq.mean()) <= 4 * se
    else:
        assert var.mean() >= sq.mean() - 4 * se


def test_a_hidden_drift_runs_on_through_a_wait_on_the_sessions_own_clock():
    """The look-alike's simulator after the session: a drift's contribution at a new pose is
    the session's linear law continued — n_k·v·(t − t_mid), t_mid the middle of the session's
    own time span — however long the wait (from the whole recording's middle instead, it
    would step back by half the time added)."""
    from hexcal.sim.plan_cases import case
    from hexcal.sim.simulate import PoseContext

    c = case("thermal vs drift", 3)
    assert c.hidden == "drift"
    m = c.meas
    mid = 0.5 * (m.t.min() + m.t.max())
    P, R = m.position[-1:], m.rotations.as_matrix()[-1:]
    per_s = []
    for wait in (0.0, 3600.0):
        t = np.array([m.t[-1] + wait + 10.0])
        got = c.history(np.zeros((1, 6)), PoseContext(P, R, t, np.array([25.0])))
        per_s.append(got[0] / (t[0] - mid))  # n_k·v, whatever the time: the law continued
    assert np.abs(per_s[0]).max() > 0
    np.testing.assert_allclose(per_s[1], per_s[0], rtol=1e-9)


def test_hexcal_plan_writes_the_schedule_it_is_asked_for_and_refuses_two_temperatures(
    tmp_path, capsys
):
    """``hexcal plan --wait S --temperature C``: the table's t column starts S + one pose's
    pace after the session's last pose, its temperature column holds C, and --json says both;
    --temperature with --can-hold is refused, and nothing is written."""
    import json

    from hexcal.app.cli import main
    from hexcal.io.measurements import write_measurements
    from hexcal.io.measurements_csv import read_measurements
    from hexcal.sim.plan_cases import case

    c = case("thermal vs drift", 3, 0.5)
    write_measurements(c.meas, tmp_path / "m.csv")
    (tmp_path / "robot.json").write_text(c.design.model_dump_json())
    (tmp_path / "instruments.json").write_text(c.instruments.model_dump_json())
    args = ["plan", str(tmp_path / "m.csv"), "--robot", str(tmp_path / "robot.json")]
    args += ["--instruments", str(tmp_path / "instruments.json"), "--separate", "thermal", "drift"]
    out = tmp_path / "plan.csv"
    assert (
        main(
            [
                *args,
                "--poses",
                "3",
                "--wait",
                "600",
                "--temperature",
                "21",
                "--out",
                str(out),
                "--json",
            ]
        )
        == 0
    )
    said = json.loads(capsys.readouterr().out)
    assert (said["wait_s"], said["temperature_c"], said["poses"]) == (600.0, 21.0, 3)
    plan = read_measurements(out)
    dt = max(float(np.median(np.diff(c.meas.t))), 1.0)
    np.testing.assert_allclose(plan.t[0], c.meas.t[-1] + 600 + dt, atol=1e-3)
    assert set(plan.temperature) == {21.0}
    refused = tmp_path / "refused.csv"
    with pytest.raises(SystemExit, match="--temperature or --can-hold"):
        main([*args, "--temperature", "21", "--can-hold", "20", "25", "--out", str(refused)])
    assert not refused.exists()
