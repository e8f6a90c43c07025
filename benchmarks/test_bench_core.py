"""Benchmarks of the core (pytest-benchmark); run with

    python -m pytest benchmarks --benchmark-only

They are not part of the test suite (no wall-clock assertion anywhere): the figures go in the
README and the closing note.
"""

from __future__ import annotations

from collections import Counter

import pytest

from hexcal.estimate.calibrate import calibrate
from hexcal.model.instruments import EncoderNoise, Instruments, TrackerNoise
from hexcal.sim.robots import left_hand
from hexcal.sim.session_sim import SessionPlan, simulate_session
from hexcal.sim.study import METHODS, StudyConfig, run_study

INST = Instruments(
    tracker=TrackerNoise(position_sigma_mm=0.01, orientation_sigma_deg=0.002),
    encoders=EncoderNoise(reading_sigma_mm=0.002),
)


@pytest.fixture(scope="module")
def session_7_7_40():
    """6 legs × (7 Type II + 7 Type III) constrained poses + 40 free poses."""
    meas, _ = simulate_session(
        left_hand(), 1, SessionPlan(n_type_i=0, n_type_ii=7, n_type_iii=7, n_free=40)
    )
    return meas


def test_bench_calibrate_model42(benchmark, session_7_7_40):
    """One whole-robot Model 42 calibration: linear seed and weighted refinement."""
    cal = benchmark(calibrate, session_7_7_40, left_hand(), 42, INST)
    assert cal.refinement is not None and cal.refinement.success


def expected_rows(config: StudyConfig) -> Counter[tuple[str, int, str]]:
    """The rows a study writes, as (pose set, N, method): every N of the clamped sweeps by each
    method (Type III twice: with the estimated and with the true b), and every free-pose set by
    the direct linear seed and the refinement (the paper has no free-pose method)."""

    def grid(pose_set: str, lo_hi: tuple[int, int], methods: tuple[str, ...] = METHODS):
        return [(pose_set, n, m) for n in range(lo_hi[0], lo_hi[1] + 1) for m in methods]

    return Counter(
        grid("type_i", config.n_type_i)
        + grid("type_ii", config.n_type_ii)
        + grid("type_iii", config.n_type_iii)
        + grid("type_iii_known_b", config.n_type_iii)
        + [("free", n, m) for n in config.n_free for m in ("direct", "refined")]
    )


def test_bench_study_full_grid(benchmark):
    """`hexcal study` at its defaults: the full N grid, 1000 trials per N, and the free-pose
    sets."""
    config = StudyConfig()
    res = benchmark.pedantic(run_study, args=(config,), rounds=1, iterations=1)
    # At the defaults: 3 methods × (47 + 27 + 26 + 26) N + 2 methods × 2 free-pose sets = 382.
    assert Counter((r["set"], r["n"], r["method"]) for r in res.rows) == expected_rows(config)


def test_bench_predict_poses_from_readings(benchmark):
    """Forward kinematics with a calibrated model (Model 42 + gain): 1000 rows of readings →
    poses (`hexcal predict`), from the robot's home as the guess."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    from hexcal.estimate.predict import LegModel

    rng = np.random.default_rng(0)
    robot = left_hand()
    model = LegModel(robot, ("gain",), rng.uniform(-1000, 1000, 6))
    P = np.asarray(robot.home.position) + rng.uniform(-20, 20, (1000, 3))
    R = Rotation.from_rotvec(rng.uniform(-0.15, 0.15, (1000, 3))).as_matrix()
    rho = model.readings(P, R)
    poses = benchmark(model.poses, rho)
    assert np.abs(poses.position - P).max() < 1e-6


def test_bench_calibrate_with_pose_accuracy(benchmark, session_7_7_40):
    """`hexcal calibrate`'s whole job: the calibration, then the pose accuracy of the drawing
    and of Model 42 on held-out poses (5 refits and forward kinematics of every pose)."""
    from hexcal.app.workflow import Inputs, calibrate_model

    inp = Inputs(session_7_7_40, left_hand(), INST, "stated", "bench")
    result = benchmark(calibrate_model, inp, 42)
    assert result.accuracy[-1].heldout
