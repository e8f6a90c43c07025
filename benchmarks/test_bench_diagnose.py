"""Benchmark of one `hexcal diagnose` on a 200-pose session (pytest-benchmark):

    python -m pytest benchmarks --benchmark-only

Every candidate scored, the leaders refitted, each fit cross-validated (random and blocked).
"""

from __future__ import annotations

import numpy as np
import pytest

from hexcal.diagnosis import diagnose
from hexcal.model.instruments import EncoderNoise, Instruments, TrackerNoise
from hexcal.sim.inject import effect_hook, realistic_values
from hexcal.sim.robots import left_hand
from hexcal.sim.session_sim import SessionPlan, perturbed_truth, simulate_session

INST = Instruments(
    tracker=TrackerNoise(position_sigma_mm=0.01, orientation_sigma_deg=0.002),
    encoders=EncoderNoise(reading_sigma_mm=0.002),
)


@pytest.fixture(scope="module")
def session_200():
    """6 legs × (8 + 8 + 8) constrained poses + 56 free poses = 200, with hidden backlash."""
    design = left_hand().model_copy(update={"platform_mass_kg": 20.0})
    rng = np.random.default_rng(7)
    plan = SessionPlan(n_free=56, temperature_rise_k=5.0)
    truth = perturbed_truth(design, rng, plan)
    hook = effect_hook("backlash", realistic_values("backlash", rng, truth), truth)
    meas, _ = simulate_session(design, 7, plan, effects=[hook], truth=truth)
    assert len(meas) == 200
    return meas, design


def test_bench_diagnose_200_poses(benchmark, session_200):
    meas, design = session_200
    d = benchmark.pedantic(
        diagnose, args=(meas, design, 42), kwargs={"instruments": INST}, rounds=3, iterations=1
    )
    assert d.verdict == "backlash"
