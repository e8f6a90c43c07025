"""Benchmarks of the core (pytest-benchmark); run with

    python -m pytest benchmarks --benchmark-only

They are not part of the test suite (no wall-clock assertion anywhere): the figures go in the
README and the closing note.
"""

from __future__ import annotations

import pytest

from hexcal.estimate.calibrate import calibrate
from hexcal.model.instruments import EncoderNoise, Instruments, TrackerNoise
from hexcal.sim.robots import left_hand
from hexcal.sim.session_sim import SessionPlan, simulate_session
from hexcal.sim.study import StudyConfig, run_study

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


def test_bench_study_full_grid(benchmark):
    """`hexcal study` at its defaults: the full N grid, 1000 trials per N."""
    res = benchmark.pedantic(run_study, args=(StudyConfig(),), rounds=1, iterations=1)
    assert len(res.rows) == 3 * (47 + 27 + 26)


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
