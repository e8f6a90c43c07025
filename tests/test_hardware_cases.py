"""Effects on hardware the defaults did not serve: compliance when the platform's mass is
unknown (c·m is fitted), and backlash of a few µm on a precision hexapod (the motion dead band
from the encoders' noise instead of a fixed 0.02 mm)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import instruments
from statcheck import floor_limit

from hexcal.diagnosis import diagnose
from hexcal.effects import EffectData, get_effect
from hexcal.effects.backlash import DEADBAND_MM, deadband_for_noise, deadband_mm, motion_state
from hexcal.estimate.effect_fit import Problem
from hexcal.estimate.predict import LegModel
from hexcal.model.noise import NoiseSigmas
from hexcal.sim.inject import effect_hook, realistic_values
from hexcal.sim.robots import PRECISE_INSTRUMENTS, precise_design, precise_session
from hexcal.sim.session_sim import SessionPlan, perturbed_truth, simulate_session
from hexcal.sim.simulate import Simulator

MASS_KG = 20.0


# -- compliance without the mass --------------------------------------------------------------
def test_compliance_without_the_mass_is_c_times_m(design, rng):
    """The basis without the mass is the 1 kg platform's: c·m times it is c times the
    basis with the mass; the parameter is compliance.cm in µm·kg/N, and predicting works."""
    with_mass = design.model_copy(update={"platform_mass_kg": MASS_KG})
    eff = get_effect("compliance")
    assert [(s.name, s.unit) for s in eff.params(with_mass)] == [("compliance.c", "µm/N")]
    assert [(s.name, s.unit) for s in eff.params(design)] == [("compliance.cm", "µm·kg/N")]
    P, R = Simulator(design).free((10,), rng)
    rho = Simulator(design).readings(P, R)
    data = EffectData(rho, P, R, np.zeros(10), None, design, design.a, design.b)
    c = 2.0
    assert np.allclose(
        eff.contribution(data, [c * MASS_KG]),
        eff.contribution(data.at_geometry(with_mass), [c]),
        rtol=1e-12,
        atol=1e-15,
    )
    assert eff.missing(data) is None and eff.cannot_predict(data) is None
    for robot, value in ((design, c * MASS_KG), (with_mass, c)):
        model = LegModel(robot, ("compliance",), [value])
        poses = model.poses(model.readings(P, R))
        assert np.allclose(poses.position, P, atol=1e-8)


@pytest.mark.parametrize("seed", [300, 301, 302])
def test_hidden_compliance_with_no_platform_mass_is_named_compliance(design, seed):
    """Hidden compliance with no platform_mass_kg is named `compliance` (c·m reported): the
    session is simulated with the mass in the truth, diagnosed with a design without it; the
    fitted c·m matches the true c × mass within its 95 % interval."""
    design = design.model_copy(update={"platform_mass_kg": MASS_KG})
    rng = np.random.default_rng(seed)
    plan = SessionPlan(temperature_rise_k=5.0)
    truth = perturbed_truth(design, rng, plan)
    c = realistic_values("compliance", rng, truth)
    meas, _ = simulate_session(
        design, seed, plan, effects=[effect_hook("compliance", c, truth)], truth=truth
    )
    no_mass = design.model_copy(update={"platform_mass_kg": None})
    before = diagnose(meas, no_mass, 42, instruments=instruments())
    assert before.verdict == "compliance", [(x.effect, x.delta_bic) for x in before.candidates]
    after = diagnose(
        meas, no_mass, 42, add=["compliance"], instruments=instruments(), problem=before.problem
    )
    (cm,) = [p for p in after.fit.params if p.name.startswith("compliance")]
    assert (cm.name, cm.unit) == ("compliance.cm", "µm·kg/N")
    assert abs(cm.value - c[0] * MASS_KG) < cm.ci95, (cm.value, cm.ci95, c[0] * MASS_KG)
    assert after.verdict == "none"
    assert after.fit.cv_rms_mm <= floor_limit(after)


# -- backlash on a precision hexapod ----------------------------------------------------------
PRECISE_INST = PRECISE_INSTRUMENTS


def test_dead_band_from_the_noise():
    assert deadband_for_noise(0.001) == pytest.approx(4 * math.sqrt(2) * 0.001)
    assert deadband_for_noise(None) == DEADBAND_MM == 0.02
    # A still leg's readings jitter by σ: a false move has odds 6e-5 per pose (0.1 expected
    # over these 300 poses × 6 legs); a 12 µm move and back shows on every leg.
    dead = deadband_for_noise(0.001)
    rng = np.random.default_rng(3)
    assert not motion_state(rng.normal(0.0, 0.001, (300, 6)), dead).any()
    steps = np.repeat([0.0, 0.012, 0.0], 50)[:, None] + rng.normal(0.0, 0.001, (150, 6))
    s = motion_state(steps, dead)
    assert (s[:50] == 0).all() and (s[50:100] == 1).all() and (s[100:] == -1).all()
    assert not motion_state(steps, DEADBAND_MM).any()  # the fixed 0.02 mm sees no move


def test_the_fit_sets_the_dead_band_from_the_stated_noise_and_the_model_keeps_it(design, rng):
    meas, _ = simulate_session(design, 5, SessionPlan(n_free=10, n_type_iii=2, n_type_ii=2))
    sig = NoiseSigmas(0.001, np.deg2rad(0.0002), 0.001)
    problem = Problem.build(meas, design, sig)
    assert problem.design.backlash_deadband_mm == pytest.approx(deadband_for_noise(0.001))
    assert deadband_mm(problem.data) == problem.design.backlash_deadband_mm
    # Unknown noise: the fallback; a dead band stated in robot.json wins over the noise.
    assert deadband_mm(Problem.build(meas, design, None).data) == DEADBAND_MM
    stated = design.model_copy(update={"backlash_deadband_mm": 0.05})
    assert Problem.build(meas, stated, sig).design.backlash_deadband_mm == 0.05


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_precision_hexapod_backlash_of_a_few_um_is_named_and_falls_to_the_floor(seed):
    """A precision hexapod (strokes ± 8 mm, noise 1 µm) with 2–5 µm of backlash is named
    `backlash` and falls to the floor (3σ: tests/statcheck.py's floor_limit). The dead band is 4·√2·1 µm = 5.7 µm; the
    fixed 0.02 mm would take the 12–40 µm moves for jitter."""
    sess = precise_session(seed)
    meas, design, beta = sess.meas, sess.design, sess.beta
    strokes = np.ptp(meas.readings, axis=0)
    assert (strokes > 10.0).all() and (strokes < 20.0).all()
    before = diagnose(meas, design, 42, instruments=PRECISE_INST)
    assert before.problem.design.backlash_deadband_mm == pytest.approx(0.004 * math.sqrt(2))
    assert before.verdict == "backlash", [(c.effect, c.delta_bic) for c in before.candidates]
    after = diagnose(
        meas, design, 42, add=["backlash"], instruments=PRECISE_INST, problem=before.problem
    )
    assert after.verdict == "none"
    assert after.fit.cv_rms_mm <= floor_limit(after)
    est = np.array([p.value for p in after.fit.params if p.name.startswith("backlash.")])
    assert np.abs(est - beta).max() < 0.0008  # within 0.8 µm
    # The calibrated model evaluates backlash with the same dead band: it predicts what the fit did.
    model = after.fit.leg_model(after.problem.design)
    assert model.robot.backlash_deadband_mm == before.problem.design.backlash_deadband_mm
    assert np.allclose(model.residuals(meas), after.fit.residuals, atol=1e-9)


def test_the_calibrated_model_file_keeps_the_dead_band_it_was_fitted_with():
    from hexcal.estimate.calibrate import calibrate
    from hexcal.estimate.model_file import CalibratedRobot, parse_model

    meas, design = precise_session(0, clusters=30).meas, precise_design()
    cal = calibrate(meas, design, 42, instruments=PRECISE_INST, effects=("backlash",), clamps=False)
    model = cal.leg_model()
    assert model.robot.backlash_deadband_mm == pytest.approx(0.004 * math.sqrt(2))
    assert np.allclose(model.residuals(meas), cal.residuals, atol=1e-9)
    # As calibrated.json: the key rides along, and the file's model predicts the same.
    data = {
        **cal.robot.model_dump(exclude_none=True),
        "calibration": {
            "format": "hexcal-calibrated-model",
            "format_version": 1,
            "model": cal.model_name,
            "kind": 42,
            "effects": [
                {"name": "backlash", "parameters": [p.model_dump() for p in _params(model)]}
            ],
            "fit": {"poses": len(meas)},
            "provenance": {"poses": len(meas)},
        },
    }
    loaded = parse_model(data, "calibrated.json")
    assert isinstance(loaded, CalibratedRobot)
    assert np.allclose(loaded.leg_model().residuals(meas), cal.residuals, atol=1e-9)


def _params(model):
    from hexcal.estimate.model_file import effect_records

    return effect_records(model)[0].parameters
