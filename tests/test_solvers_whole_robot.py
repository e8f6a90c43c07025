"""Whole-robot linear calibration: which method serves which leg, and refusals."""

from __future__ import annotations

import numpy as np
import pytest

from hexcal.estimate.solvers.whole_robot import CalibrationRefused, calibrate_linear
from hexcal.sim.session_sim import SessionPlan, simulate_session
from hexcal.sim.simulate import NoiseModel

CLEAN = SessionPlan(noise=NoiseModel(), resolution=None)


def _run(meas, model, design, form="paper"):
    return calibrate_linear(
        meas.position,
        meas.rotations.as_matrix(),
        meas.readings,
        meas.leg,
        meas.constraint,
        model,
        design.offsets,
        form,
    )


@pytest.mark.parametrize("form", ["paper", "direct"])
@pytest.mark.parametrize("model", [36, 42])
def test_noise_free_whole_robot(design, model, form):
    meas, truth = simulate_session(design, seed=3, plan=CLEAN)
    lin = _run(meas, model, truth if model == 36 else design, form)
    assert np.max(np.abs(lin.a - truth.a)) < 1e-9 * 200
    assert np.max(np.abs(lin.b - truth.b)) < 1e-9 * 200
    assert np.max(np.abs(lin.offsets - truth.offsets)) < 1e-9 * 200
    expected = "§3.2" if model == 36 else "§3.3"
    assert all(m.startswith(expected) for m in lin.methods)


def test_falls_back_to_33_then_free(design):
    meas, truth = simulate_session(design, seed=4, plan=CLEAN)
    no_type_i = meas.subset(meas.constraint != "direction")
    lin = _run(no_type_i, 36, truth)
    assert all(m.startswith("§3.3") for m in lin.methods)
    free_only = meas.subset(meas.leg == 0)
    lin = _run(free_only, 42, design)
    assert all(m.startswith("free-linear") for m in lin.methods)
    assert np.max(np.abs(lin.a - truth.a)) < 1e-7


def test_refusal_lists_every_leg_and_what_to_add(design):
    meas, _ = simulate_session(
        design, seed=5, plan=SessionPlan(n_type_i=0, n_type_ii=0, n_type_iii=0, n_free=10)
    )
    with pytest.raises(CalibrationRefused) as exc:
        _run(meas, 42, design)
    text = str(exc.value)
    for k in range(1, 7):
        assert f"leg {k}:" in text
    assert "Type II (direction and length clamped)" in text and "at least 17" in text
