"""The metrology figures (hexcal.diagnosis.metrology): ISO 9283 against its formulas and a
Monte-Carlo of the same robot and noise, ISO 230-2's reversal value against the hidden play,
the test cube, and the procedure steps that record the tests."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hexcal.diagnosis.iso230_2 import leg_figures, leg_positioning
from hexcal.diagnosis.iso9283 import figures_at_pose, iso9283
from hexcal.diagnosis.metrology import metrology
from hexcal.estimate.predict import LegModel, Poses
from hexcal.model.iso_tests import iso230_targets, iso9283_cube, iso9283_sequence
from hexcal.model.noise import NoiseSigmas
from hexcal.model.workspace import Workspace
from hexcal.sim.inject import realistic_values
from hexcal.sim.metrology_sim import drive, iso9283_commands, simulate_tests, true_model
from hexcal.sim.robots import left_hand
from hexcal.sim.session_sim import SessionPlan, perturbed_truth
from hexcal.sim.simulate import NoiseModel

NOISE = NoiseModel(0.01, 0.002, 0.002)
SIG = NoiseSigmas(0.01, np.deg2rad(0.002), 0.002)


def _robot(seed: int, effect: str):
    """(design, truth robot, true model with the effect hidden, the effect's true values)."""
    design = left_hand()
    rng = np.random.default_rng(seed)
    truth = perturbed_truth(design, rng, SessionPlan())
    values = realistic_values(effect, rng, truth)
    return design, truth, true_model(truth, (effect,), values), values


# -- ISO 9283 ---------------------------------------------------------------------------------
def test_the_cube_is_the_largest_the_stroke_allows_and_its_poses_follow_the_standard():
    robot = left_hand()
    cube = iso9283_cube(robot)
    labels, P, R = cube.poses()
    assert labels == ["P1", "P2", "P3", "P4", "P5"]
    assert np.allclose(P[0], robot.home.position)
    corners = list(cube.corners.values())
    diagonal = cube.edge * np.sqrt(3)
    for p, c in zip(P[1:], corners, strict=True):  # 10 % of the diagonal from its corner
        assert np.linalg.norm(p - c) == pytest.approx(0.1 * diagonal)
    ws = Workspace(robot)
    home = np.array([ws.home_leg(k)[1] for k in range(6)]) - robot.offsets
    readings = ws.true_lengths(np.array(corners), R[:4]) - robot.offsets
    assert np.abs(readings - home).max() <= 30.0 + 1e-9  # the stroke holds at the corners...
    grown = iso9283_cube(robot.model_copy(update={"leg_range_mm": [-1e3, 1e3]}))
    assert grown.edge > cube.edge  # ...and is what limits the edge
    assert "leg_range_mm" in grown.reason


def test_the_figures_of_one_test_pose_follow_the_formulas():
    """AP_P is the distance between the barycentres, RP_l = l̄ + 3 S_l, RP_a = 3 S_a."""
    rng = np.random.default_rng(0)
    n = 30
    commanded = Poses(np.tile([1.0, 2.0, 3.0], (n, 1)), np.tile(np.eye(3), (n, 1, 1)))
    scatter = rng.normal(0, 0.01, (n, 3))
    rv = rng.normal(0, 1e-4, (n, 3))
    attained = Poses(
        commanded.position + [0.03, -0.04, 0.0] + scatter,
        Rotation.from_rotvec(rv + [2e-3, 0, 0]).as_matrix(),
    )
    f = figures_at_pose("P1", attained, commanded)
    assert f.ap_p_mm == pytest.approx(np.linalg.norm([0.03, -0.04, 0.0] + scatter.mean(0)))
    l_j = np.linalg.norm(scatter - scatter.mean(0), axis=1)
    assert f.rp_l_mm == pytest.approx(l_j.mean() + 3 * l_j.std(ddof=1))
    a = Rotation.from_rotvec(rv + [2e-3, 0, 0]).as_euler("xyz", degrees=True)
    assert f.ap_deg[0] == pytest.approx(a[:, 0].mean())
    assert f.rp_deg == pytest.approx(3 * a.std(axis=0, ddof=1))


def _mc_figures(truth, model, commands, rng):
    """ISO 9283 figures of one repetition of the test, computed here without hexcal's
    metrology: the physics of the simulator, then the standard's formulas by hand."""
    P, R, rho = drive(truth, commands, rng, NOISE, NOISE.sigma_reading_mm)
    solved, closed = model.solve_poses(rho, guess=Poses(P, R))
    assert closed.all()
    out = []
    for i in range(5):
        idx = np.arange(i, len(P), 5)
        x, xc = P[idx], solved.position[idx]
        l_j = np.linalg.norm(x - x.mean(0), axis=1)
        ang = Rotation.from_matrix(R[idx]).as_euler("xyz", degrees=True)
        ang_c = Rotation.from_matrix(solved.rotation[idx]).as_euler("xyz", degrees=True)
        out.append(
            [
                np.linalg.norm(x.mean(0) - xc.mean(0)),
                *(ang.mean(0) - ang_c.mean(0)),
                l_j.mean() + 3 * l_j.std(ddof=1),
            ]
        )
    return np.array(out)  # (5 poses, AP_P, AP_a, AP_b, AP_c, RP_l)


def test_iso9283_agrees_with_a_monte_carlo_of_the_same_robot_and_noise():
    """A robot hiding a gain, driven by its drawing, judged with its true geometry (the gain
    left out): hexcal's AP and RP on ten simulated ``iso9283`` sessions, averaged, against 200
    repetitions of the same test computed by hand — within three standard errors of the
    ten sessions' mean (and the systematic AP the gain causes is far above the noise)."""
    design, truth, true, _ = _robot(4, "gain")
    model = LegModel(truth)  # the geometry, no gain: AP is the gain's pose error
    rng = np.random.default_rng(40)
    sessions = []
    for _ in range(10):
        meas = simulate_tests(true, design, rng, NOISE, tests=("iso9283",))
        fig = iso9283(model, meas)
        assert fig is not None and [p.label for p in fig.poses] == ["P1", "P2", "P3", "P4", "P5"]
        assert all(p.visits == 30 for p in fig.poses) and fig.left_out == 0
        sessions.append([[p.ap_p_mm, *p.ap_deg, p.rp_l_mm] for p in fig.poses])
    ours = np.array(sessions)  # (10, 5, 5)
    commands, _ = iso9283_commands(LegModel(design), design)
    mc = np.array([_mc_figures(true, model, commands, rng) for _ in range(200)])
    se = mc.std(axis=0, ddof=1) / np.sqrt(len(ours))
    z = (ours.mean(axis=0) - mc.mean(axis=0)) / se
    assert np.abs(z).max() < 3.0, z
    assert (mc[:, :, 0].mean(0) > 5 * mc[:, :, 0].std(0)).all()  # AP_P: systematic, not noise


# -- ISO 230-2 --------------------------------------------------------------------------------
def test_the_positioning_figures_follow_the_formulas():
    """Two targets, three approaches each way, made-up deviations: A, R, B by hand."""
    readings, dev = [], []
    up = {10.0: [0.010, 0.012, 0.014], 20.0: [0.020, 0.018, 0.022]}
    down = {10.0: [-0.010, -0.008, -0.012], 20.0: [0.000, 0.004, 0.002]}
    for c in range(3):
        readings += [5.0, 10.0, 20.0, 25.0, 20.0, 10.0]
        dev += [0.0, up[10.0][c], up[20.0][c], 0.0, down[20.0][c], down[10.0][c]]
    fig = leg_figures(3, np.array(readings), np.array(dev), 0.005)
    assert fig is not None and fig.targets == 2 and fig.approaches == 12
    mu = {t: np.mean(v) for t, v in up.items()}
    md = {t: np.mean(v) for t, v in down.items()}
    su = {t: np.std(v, ddof=1) for t, v in up.items()}
    sd = {t: np.std(v, ddof=1) for t, v in down.items()}
    b = {t: mu[t] - md[t] for t in up}
    assert fig.reversal_mm == pytest.approx(max(abs(v) for v in b.values()))
    assert fig.mean_reversal_mm == pytest.approx(np.mean(list(b.values())))
    r = max(max(2 * su[t] + 2 * sd[t] + abs(b[t]), 4 * su[t], 4 * sd[t]) for t in up)
    assert fig.repeatability_mm == pytest.approx(r)
    hi = max(max(mu[t] + 2 * su[t], md[t] + 2 * sd[t]) for t in up)
    lo = min(min(mu[t] - 2 * su[t], md[t] - 2 * sd[t]) for t in up)
    assert fig.accuracy_mm == pytest.approx(hi - lo)


#: Real axes through ISO 230-2's linear test cycle (five targets, five cycles), as the Paul
#: Scherrer Institute's ecmc motion-test reports give them. ``psi``: a reference encoder's
#: positions (mm) in the report's forward and backward tables, per target and cycle
#: (github.com/paulscherrerinstitute/ecmccfg, examples/test/fat_sat/report.md,
#: 2023-12-08). ``muts``: a drifting axis, its deviations (mm) as the report prints them
#: (github.com/anderssandstrom/ecmc_target_muts_logger,
#: muts/data/week42_22/xyz/target_x_report_8A.md, 2022-10-20).
ECMC_PSI_TARGETS = [-10.0, -4.88, 0.24, 5.36, 10.48]
ECMC_PSI_FORWARD = [
    [-10.00008102, -10.00010202, -10.00008702, -10.00009202, -10.00010002],
    [-4.88008702, -4.88009702, -4.88009702, -4.88009502, -4.88008202],
    [0.23992798, 0.23990998, 0.23991198, 0.23991298, 0.23991298],
    [5.35989798, 5.35991398, 5.35991398, 5.35990698, 5.35992198],
    [10.47989998, 10.47988798, 10.47987098, 10.47989098, 10.47990298],
]
ECMC_PSI_BACKWARD = [
    [-10.00009902, -10.00009402, -10.00008202, -10.00009102, -10.00009402],
    [-4.88010302, -4.88010402, -4.88009502, -4.88011102, -4.88009302],
    [0.23991398, 0.23989798, 0.23990898, 0.23992398, 0.23990098],
    [5.35992798, 5.35990798, 5.35990498, 5.35989698, 5.35991898],
    [10.47989598, 10.47987398, 10.47986998, 10.47985898, 10.47989298],
]
ECMC_MUTS_TARGETS = [-4.0, -2.0, 0.0, 2.0, 4.0]
ECMC_MUTS_FORWARD_DEV = [
    [0.00139, 0.01634, 0.01634, 0.04988, 0.04665],
    [-0.00655, 0.01164, 0.01891, 0.0581, 0.06659],
    [-0.02782, -0.00802, -0.01005, 0.01986, 0.0344],
    [-0.02526, -0.00384, 0.00181, 0.03495, 0.04909],
    [0.00316, 0.00397, 0.00963, 0.03024, 0.05165],
]
ECMC_MUTS_BACKWARD_DEV = [
    [-0.10205, -0.01598, 0.00139, 0.00746, 0.03857],
    [-0.11969, -0.02392, -0.00251, 0.00032, 0.0383],
    [-0.13005, -0.02904, -0.01489, -0.01126, 0.01622],
    [-0.05233, -0.02809, -0.01152, 0.00949, 0.02323],
    [-0.05017, -0.01946, -0.01462, 0.01731, 0.03024],
]
#: The figures each report prints (mm): A↑, A↓, A, B, B̄, R (its per-target R(i)'s largest),
#: E↑, E↓, M; and E over both directions, computed here by the standard from the report's mean
#: deviations, the highest less the lowest (``psi``: target 3 forward −8.482e-05 less target 5
#: backward −12.162e-05; ``muts``: target 2 forward 0.02974 less target 3 backward −0.0338).
#: With the tolerance each report's rounding leaves.
ECMC_FIGURES = {
    "psi": (
        dict(A_up=6.428e-05, A_down=8.881e-05, A=8.881e-05, B=1.22e-05, B_mean=5.4e-06,
             R=6.882e-05, E_up=2.46e-05, E_down=3.3e-05, M=2.77e-05, E=3.68e-05),
        dict(rel=1e-3, abs=0.0),
    ),
    "muts": (
        dict(A_up=0.14139, A_down=0.24337, A=0.24337, B=0.05124, B_mean=0.03544,
             R=0.23715, E_up=0.02806, E_down=0.02646, M=0.02226, E=0.06354),
        dict(rel=0.0, abs=2e-5),
    ),
}  # fmt: skip


def _ecmc_cycle(case: str) -> tuple[np.ndarray, np.ndarray]:
    """(readings, deviations) of one leg through the report's cycle: from below the first
    target, 1 → 5, an overrun past the last, 5 → 1, an overrun below the first, five times."""
    if case == "psi":
        targets = ECMC_PSI_TARGETS
        fwd = np.array(ECMC_PSI_FORWARD) - np.array(targets)[:, None]
        bwd = np.array(ECMC_PSI_BACKWARD) - np.array(targets)[:, None]
    else:
        targets = ECMC_MUTS_TARGETS
        fwd, bwd = np.array(ECMC_MUTS_FORWARD_DEV), np.array(ECMC_MUTS_BACKWARD_DEV)
    below, above = targets[0] - 2.0, targets[-1] + 2.0
    readings, dev = [below], [0.0]
    for c in range(5):
        readings += [*targets, above, *reversed(targets), below]
        dev += [*fwd[:, c], 0.0, *bwd[::-1, c], 0.0]
    return np.array(readings), np.array(dev)


@pytest.mark.parametrize("case", sorted(ECMC_FIGURES))
def test_the_positioning_figures_agree_with_a_peer_implementation_on_real_axes(case):
    """ecmc's reports on the two axes above, each fed through :func:`leg_figures` as one leg
    (the target its reading, the deviation the reference's position less it). Both follow
    ISO 230-2 alike for A↑, A↓, A, B, B̄, R = max R_i, E↑, E↓ and M. Where a report's axis
    figure departs from the standard, hexcal keeps the standard's: ecmc's axis R is
    max(R↑, R↓) (6.29e-05 mm for ``psi``), and its E subtracts the larger of the two
    directions' lowest means where the standard takes the lowest of all (its ``calcE``:
    2.46e-05 mm and 0.02806 mm)."""
    expected, tol = ECMC_FIGURES[case]
    fig = leg_figures(1, *_ecmc_cycle(case), 1e-6)
    assert fig is not None and fig.targets == 5 and fig.approaches == 50
    got = dict(
        A_up=fig.accuracy_up_mm,
        A_down=fig.accuracy_down_mm,
        A=fig.accuracy_mm,
        B=fig.reversal_mm,
        B_mean=fig.mean_reversal_mm,
        R=fig.repeatability_mm,
        E_up=fig.systematic_up_mm,
        E_down=fig.systematic_down_mm,
        M=fig.mean_bidirectional_mm,
        E=fig.systematic_mm,
    )
    assert got == pytest.approx(expected, **tol)


def test_the_reversal_value_matches_the_hidden_play_within_two_sigma():
    """Twelve robots hiding backlash, each leg through ISO 230-2's test cycle (simulated in
    joint space): −B̄ against the true play of each leg, in units of its stated σ. 95 % of the
    72 legs lie within 2σ when σ is right: at least 62 must (binomial 0.1 % tail); the
    z-scores' mean is within 4/√72 of 0 and their standard deviation within 4/√(2·72) of 1
    (4σ: the mean's and the sample standard deviation's spreads for 72 normal draws)."""
    z = []
    for seed in range(12):
        design, truth, true, beta = _robot(100 + seed, "backlash")
        meas = simulate_tests(true, design, np.random.default_rng(seed), NOISE, tests=("iso230-2",))
        legs = leg_positioning(LegModel(truth), meas)
        assert [p.leg for p in legs] == [1, 2, 3, 4, 5, 6]
        assert all(p.targets == 5 and p.approaches == 50 for p in legs)
        z += [(-p.mean_reversal_mm - beta[p.leg - 1]) / p.mean_reversal_sigma_mm for p in legs]
    z = np.array(z)
    assert (np.abs(z) <= 2).sum() >= 62, z
    n = z.size
    assert abs(z.mean()) < 4 / np.sqrt(n) and abs(z.std() - 1) < 4 / np.sqrt(2 * n), (
        z.mean(),
        z.std(),
    )


def test_the_targets_of_each_leg_keep_the_others_at_home():
    robot = left_hand()
    t = iso230_targets(robot, 2)
    readings, direction = t.sequence(2)
    assert len(readings) == 2 * 2 * (len(t.targets) + 1)
    assert np.allclose(np.delete(readings, 1, axis=1), np.delete(t.hold, 1))
    assert set(direction.tolist()) == {-1, 1}
    assert np.all(np.diff(t.targets) > 0)


# -- the whole module, and the steps that record the tests -------------------------------------
def test_metrology_finds_both_tests_in_one_session():
    design, truth, true, _ = _robot(7, "backlash")
    meas = simulate_tests(true, design, np.random.default_rng(3), NOISE)
    fig = metrology(LegModel(truth), "truth", meas, SIG, None, "none given")
    assert fig.iso9283 is not None and len(fig.iso9283.poses) == 5
    assert len(fig.iso230_2) == 6
    assert (
        fig.uncertainty is not None and "readings' noise only: none given" in fig.uncertainty.source
    )
    text = "\n".join(fig.lines())
    assert "ISO 9283" in text and "ISO 230-2" in text and "AP_P" in text
    d = fig.to_dict()
    assert d["iso9283"]["poses"][0]["cycles"] == 30 and len(d["iso230_2"]) == 6


def test_the_procedure_steps_visit_the_tests_targets_on_the_mock_rig():
    """The shipped iso9283 and iso230-2 procedures, run by the scripted operator on the mock
    rig: the platform visits the five test poses 30 times and each leg its targets."""
    from hexcal.acquire.acquisition import StillWindow
    from hexcal.mock_hw.instant import InstantAcquisition
    from hexcal.mock_hw.motion import MockMotionController
    from hexcal.mock_hw.robot import MockRobot
    from hexcal.procedure.recording import RunSettings, record_procedure
    from hexcal.procedure.steps import load_procedure

    design = left_hand()
    truth = perturbed_truth(design, np.random.default_rng(5), SessionPlan())
    robot = MockRobot(truth, seed=5)
    steps = load_procedure("iso9283").expand() + load_procedure("iso230-2").expand()
    session = record_procedure(
        InstantAcquisition(robot, StillWindow(duration_s=0.1)),
        MockMotionController(robot, seed=5),
        steps,
        float(np.linalg.norm(truth.b, axis=1).max()),
        RunSettings(settle_s=0.0),
        design=design,
    )
    meas = session.measurements()
    assert list(dict.fromkeys(meas.step)) == ["iso9283", "iso230-2"]
    _, P, _ = iso9283_sequence(design)
    iso = meas.subset(meas.step == "iso9283")
    assert len(iso) == 150 and np.abs(iso.position - P).max() < 0.1  # the tracker's noise
    fig = metrology(LegModel(truth), "truth", meas, SIG, None)
    assert fig.iso9283 is not None and [p.visits for p in fig.iso9283.poses] == [30] * 5
    assert len(fig.iso230_2) == 6 and all(p.targets == 5 for p in fig.iso230_2)


def test_simulate_appends_the_tests_to_a_session(tmp_path):
    from hexcal.app.cli import main
    from hexcal.io.measurements_csv import read_measurements

    out = tmp_path / "s"
    args = ["simulate", "--out", str(out), "--seed", "2", "--n-free", "10"]
    assert main([*args, "--effect", "thermal", "--tests", "iso9283", "iso230-2"]) == 0
    meas = read_measurements(out / "measurements.csv")
    steps = list(dict.fromkeys(meas.step))
    assert steps[-2:] == ["iso9283", "iso230-2"]
    assert (meas.step == "iso9283").sum() == 150 and (meas.step == "iso230-2").sum() == 360
    assert np.all(np.diff(meas.t) > 0) and len(set(meas.pose_id)) == len(meas)
