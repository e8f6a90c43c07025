"""Whole-robot calibration: the fallback start from the design when the linear seed's fit fails,
and the test of the clamps' constraints."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hexcal.app.report_text import calibration_json, calibration_text
from hexcal.estimate.calibrate import (
    RETRY_CHI2_PER_DOF,
    calibrate,
    leg_residuals,
    refine_from_seeds,
)
from hexcal.estimate.layout import ParameterLayout
from hexcal.estimate.refine import refine
from hexcal.estimate.solvers.free import free_linear
from hexcal.io.measurements import Measurements
from hexcal.model.instruments import EncoderNoise, Instruments, TrackerNoise
from hexcal.model.noise import NoiseSigmas
from hexcal.sim.inject import effect_hook, realistic_values
from hexcal.sim.robots import left_hand
from hexcal.sim.session_sim import SessionPlan, perturbed_truth, simulate_session
from hexcal.sim.simulate import NoiseModel, PoseRanges, Simulator

TRUTH = left_hand()
NOISE = NoiseModel(0.1, 0.01, 0.1, "gaussian")
SIG = NoiseSigmas(NOISE.sigma_position_mm, NOISE.sigma_orientation_rad, NOISE.sigma_reading_mm)


def _free_poses(seed: int, n: int = 20):
    sim = Simulator(TRUTH, ranges=PoseRanges(box_mm=(30.0, 30.0, 30.0)), noise=NOISE)
    rng = np.random.default_rng(seed)
    return sim.measure(rng, *sim.free((n,), rng)), rng


def test_a_failed_fit_is_tried_again_from_the_design_and_says_so():
    """20 free poses (kept from a study trial) on which the fit from the free-pose linear seed
    stops in a local minimum: the fallback start from a design 1 mm off the truth reaches the
    noise, and the notes say what happened."""
    doc = json.loads((Path(__file__).parent / "data" / "free_seed_trap.json").read_text())
    P = np.array(doc["position_mm"])
    R = Rotation.from_quat(doc["quaternion_wxyz"], scalar_first=True).as_matrix()
    rho = np.array(doc["readings_mm"])
    lin = [free_linear(P, R, rho[:, k]) for k in range(6)]
    a0, b0 = np.array([s[1] for s in lin]), np.array([s[0] for s in lin])
    off0 = np.array([s[2] for s in lin])
    alone = refine(P, R, rho, a0, b0, off0, True, SIG)
    assert alone.chi2 / alone.dof > RETRY_CHI2_PER_DOF  # the trap still springs
    rng = np.random.default_rng(0)
    design = TRUTH.with_geometry(
        TRUTH.a + rng.normal(0, 1.0, (6, 3)), TRUTH.b + rng.normal(0, 1.0, (6, 3)), TRUTH.offsets
    )
    ref = refine_from_seeds(P, R, rho, a0, b0, off0, design, True, SIG)
    assert ref.chi2 / ref.dof < 2.0
    (note,) = [n for n in ref.notes if "started from the design's geometry" in n]
    # the figures it states are the two fits' (the trapped one's and the kept one's χ²/dof)
    assert f"stopped at χ²/dof {alone.chi2 / alone.dof:.1f};" in note, note
    assert f"it reached {ref.chi2 / ref.dof:.2f}:" in note, note


def test_a_good_fit_is_not_tried_again():
    (P, R, rho), _ = _free_poses(2)
    far_design = TRUTH.with_geometry(TRUTH.a + 500.0, TRUTH.b, TRUTH.offsets)
    ref = refine_from_seeds(P, R, rho, TRUTH.a, TRUTH.b, TRUTH.offsets, far_design, True, SIG)
    assert ref.chi2 / ref.dof < RETRY_CHI2_PER_DOF and not any("design" in n for n in ref.notes)


# --------------------------------------------------------------------------------------------
# The clamps' constraints: used when the clamps held, refused (and said why) when not.

INST = Instruments(
    tracker=TrackerNoise(position_sigma_mm=0.01, orientation_sigma_deg=0.002),
    encoders=EncoderNoise(reading_sigma_mm=0.002),
)


def _slipped_session(design, seed: int, slip_mm: float, leg: int = 2):
    """A session whose leg-``leg`` direction-and-length clamp slid ``slip_mm`` along x over its
    step: the platform point no longer stays at one point in space, while every pose's leg
    lengths stay true."""
    plan = SessionPlan(noise=NoiseModel(), resolution=None)
    meas, truth = simulate_session(design, seed, plan)
    P, R = meas.position.copy(), meas.rotations.as_matrix()
    rows = np.where((meas.leg == leg) & (meas.constraint == "direction+length"))[0]
    P[rows, 0] += np.linspace(0.0, slip_mm, len(rows))
    sim = Simulator(truth, noise=SessionPlan().noise)
    Pm, Rm, rho = sim.measure(np.random.default_rng(seed), P, R)
    q = Rotation.from_matrix(Rm).as_quat(scalar_first=True)
    return Measurements.from_arrays(
        Pm, q, rho, leg=meas.leg, constraint=meas.constraint, step=meas.step
    ), truth


def test_clamps_that_held_are_used(design):
    meas, _ = simulate_session(design, 5, SessionPlan())
    cal = calibrate(meas, design, 42, INST)
    check = cal.clamp_check
    assert check is not None and check.used and not check.model_misfit
    assert check.steps == 18
    assert check.ratio < check.limit
    assert cal.refinement.clamp_steps is not None
    assert "clamp constraints used" in calibration_text(cal, "s", "n")
    assert json.loads(calibration_json(cal, "s", "n"))["clamp_check"]["used"] is True
    plain = calibrate(meas, design, 42, INST, clamps=False)
    assert plain.clamp_check is None and plain.refinement.clamp_steps is None


def test_a_slipping_clamp_is_refused_and_named(design):
    """A 0.1 mm slide of one clamp over its step (ten times the tracker's noise): the rows the
    clamps add raise χ² far beyond their share, the fit from the leg lengths is kept, and the
    report says the clamps did not hold. The same poses without the slide pass."""
    held = calibrate(_slipped_session(design, 6, 0.0)[0], design, 42, INST).clamp_check
    assert held.used
    meas, truth = _slipped_session(design, 6, 0.1)
    cal = calibrate(meas, design, 42, INST)
    check = cal.clamp_check
    assert not check.used and not check.model_misfit
    assert check.ratio > check.limit
    assert cal.refinement is check.lengths_only
    assert "did not hold" in check.text and "slipped" in check.text
    # The lengths-only geometry is unharmed by the slip (the lengths were true): each of the 42
    # parameters within 4 of its own σ (the fit's covariance; all 42 inside with p 0.997).
    err = cal.refinement.x - ParameterLayout.for_model(42).pack(truth.a, truth.b, truth.offsets)
    assert np.all(np.abs(err) < 4 * cal.refinement.sigma), np.max(
        np.abs(err) / cal.refinement.sigma
    )


def test_a_missing_effect_is_not_blamed_on_the_clamps(design):
    """Encoder gain hidden in the data: the leg lengths alone already misfit, so the clamps are
    not judged (and not used) until the effect is added; then they are."""
    rng = np.random.default_rng(3)
    truth = perturbed_truth(design, rng, SessionPlan())
    hook = effect_hook("gain", realistic_values("gain", rng, truth), truth)
    meas, _ = simulate_session(design, 3, SessionPlan(), effects=[hook], truth=truth)
    without = calibrate(meas, design, 42, INST).clamp_check
    assert without.model_misfit and not without.used
    assert "misses an effect" in without.text
    with_gain = calibrate(meas, design, 42, INST, effects=("gain",))
    assert with_gain.clamp_check.used
    assert with_gain.refinement.clamp_steps is not None
    assert sum(n.startswith("gain.") for n in with_gain.refinement.names) == 6


def test_clamps_that_fit_as_well_as_a_misfit_model_are_used_and_the_effect_named(design):
    """Backlash hidden in a short session (4 + 4 clamped poses per leg, 12 free): the leg lengths
    alone misfit; the clamp rows, judged against that misfit, pass and are used, and the report
    names the missing effect instead of saying only that the clamps held."""
    plan = SessionPlan(n_type_i=0, n_type_ii=4, n_type_iii=4, n_free=12)
    rng = np.random.default_rng(1)
    truth = perturbed_truth(design, rng, plan)
    hook = effect_hook("backlash", realistic_values("backlash", rng, truth), truth)
    meas, _ = simulate_session(design, 1, plan, effects=[hook], truth=truth)
    check = calibrate(meas, design, 42, INST).clamp_check
    assert check.model_misfit and check.used
    assert "misses an effect" in check.text and "the clamps held" not in check.text


def _gain_session(design):
    rng = np.random.default_rng(3)
    truth = perturbed_truth(design, rng, SessionPlan())
    hook = effect_hook("gain", realistic_values("gain", rng, truth), truth)
    meas, _ = simulate_session(design, 3, SessionPlan(), effects=[hook], truth=truth)
    return meas


def test_an_effect_fit_weighs_the_rows_by_the_stated_noise(design):
    """Gain hidden, the session's noise that of INST: calibrated with gain and the noise stated
    twice too large, χ²/dof is a quarter of what the stated INST gives (the rows weighed by
    1/σ², not by the typical instruments'), within 4 σ of 1/4, σ = √(2/dof)/4."""
    meas = _gain_session(design)
    doubled = Instruments(
        tracker=TrackerNoise(position_sigma_mm=0.02, orientation_sigma_deg=0.004),
        encoders=EncoderNoise(reading_sigma_mm=0.004),
    )
    r = calibrate(meas, design, 42, doubled, effects=("gain",)).refinement
    assert r.chi2 / r.dof == pytest.approx(0.25, abs=4 * np.sqrt(2 / r.dof) / 4)


def test_leg_residuals_are_reading_plus_offset_less_the_legs_length():
    """Reading + offset − ‖p + R b_k − a_k‖ for each pose and leg, by hand, and zero on
    noise-free readings of the geometry itself."""
    sim = Simulator(TRUTH, ranges=PoseRanges(box_mm=(30.0, 30.0, 30.0)))
    rng = np.random.default_rng(6)
    P, R = sim.free((5,), rng)
    lengths = np.linalg.norm(P[:, None] + np.einsum("mij,kj->mki", R, TRUTH.b) - TRUTH.a, axis=-1)
    rho = lengths - TRUTH.offsets
    q = Rotation.from_matrix(R).as_quat(scalar_first=True)
    meas = Measurements.from_arrays(P, q, rho)
    assert np.allclose(leg_residuals(TRUTH.a, TRUTH.b, TRUTH.offsets, meas), 0.0, atol=1e-9)
    off = TRUTH.offsets + 1.5
    got = leg_residuals(TRUTH.a + 2.0, TRUTH.b, off, meas)
    for m in range(5):
        for k in range(6):
            want = rho[m, k] + off[k] - np.linalg.norm(P[m] + R[m] @ TRUTH.b[k] - TRUTH.a[k] - 2.0)
            assert got[m, k] == pytest.approx(want, abs=1e-9)
