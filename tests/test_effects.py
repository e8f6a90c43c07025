"""The effect catalogue: every unit honours the contract, and a session simulated with an effect
is fitted back to the true values within their reported uncertainty."""

from __future__ import annotations

import numpy as np
import pytest

from hexcal.effects import CATALOGUE, Effect, EffectData, ParamSpec, get_effect, register
from hexcal.effects.backlash import motion_state
from hexcal.effects.compliance import leg_forces
from hexcal.estimate.effect_fit import Problem, fit_model
from hexcal.model.noise import NoiseSigmas
from hexcal.sim.inject import effect_hook, realistic_values
from hexcal.sim.session_sim import SessionPlan, perturbed_truth, simulate_session
from hexcal.sim.simulate import NoiseModel

NAMES = ("offset", "gain", "backlash", "thermal", "compliance", "leadscrew")
SIG = NoiseSigmas(0.01, np.deg2rad(0.002), 0.002)


def test_catalogue_names_are_the_cli_vocabulary():
    assert set(NAMES) <= set(CATALOGUE)
    with pytest.raises(ValueError, match=r"unknown effect 'warp'.*catalogue has"):
        get_effect("warp")


@pytest.mark.parametrize("name", NAMES)
def test_contract(name, design):
    eff = get_effect(name)
    assert eff.physics.endswith(".") and eff.separating_motion
    specs = eff.params(design.model_copy(update={"platform_mass_kg": 10.0}))
    assert specs and all(
        isinstance(s, ParamSpec) and s.plausible[0] < s.plausible[1] for s in specs
    )
    # Identifiability is judged on its own scale, not on the (user-settable) plausible range.
    assert all(s.resolution is not None and s.resolution > 0 for s in specs)
    prefix = "offset" if name == "offset" else f"{name}."
    assert all(s.name.startswith(prefix) for s in specs)


def test_adding_an_effect_is_one_unit_and_its_registration(design):
    @register
    class Sag(Effect):
        name = "test-sag"
        physics = "A test effect."
        separating_motion = "any"

        def params(self, robot):
            return [ParamSpec("test-sag.s", "mm", (0.0, 1.0))]

        def basis(self, data):
            return np.ones((len(data), 6, 1))

    try:
        assert get_effect("test-sag").params(design)[0].name == "test-sag.s"
    finally:
        del CATALOGUE["test-sag"]


def test_motion_state_keeps_state_of_a_leg_that_did_not_move():
    r = np.array([[0.0], [1.0], [1.0], [0.5], [0.5], [0.505], [2.0]]) * np.ones((1, 6))
    s = motion_state(r)[:, 0]
    assert s.tolist() == [0, 1, 1, -1, -1, -1, 1]


def test_backlash_cannot_know_a_leg_before_its_first_move(design):
    """Before a leg first moves in the session, the side of its play it rests on was set by a
    move nobody recorded: those readings are ``unknown``; every other effect knows them all."""
    r = np.zeros((5, 6))
    r[2:, 0] = 1.0  # leg 1 moves at the third pose
    r[1:, 1] = np.arange(1, 5)  # leg 2 at the second; legs 3–6 never move
    m = len(r)
    data = EffectData(
        r,
        np.zeros((m, 3)),
        np.repeat(np.eye(3)[None], m, 0),
        np.arange(float(m)),
        None,
        design,
        design.a,
        design.b,
    )
    unknown = get_effect("backlash").unknown(data)
    assert unknown is not None
    assert unknown[:, 0].tolist() == [True, True, False, False, False]
    assert unknown[:, 1].tolist() == [True, False, False, False, False]
    assert unknown[:, 2:].all()
    assert all(get_effect(n).unknown(data) is None for n in CATALOGUE if n != "backlash")


def test_leg_forces_balance_the_weight(design, rng):
    from hexcal.sim.simulate import Simulator

    sim = Simulator(design)
    P, R = sim.free((20,), rng)
    data = EffectData(sim.readings(P, R), P, R, np.zeros(20), None, design, design.a, design.b)
    f = leg_forces(data, 10.0)
    v = data.leg_vectors
    n = v / np.linalg.norm(v, axis=-1, keepdims=True)
    total = np.einsum("mk,mki->mi", f, n)  # compression pushes the platform along +n
    assert np.allclose(total, [0, 0, 10.0 * 9.80665], atol=1e-9)
    # With the weight at the platform origin, the legs' moments about it cancel.
    rb = np.einsum("mij,kj->mki", R, design.b)
    assert np.allclose(np.einsum("mk,mki->mi", f, np.cross(rb, n)), 0.0, atol=1e-7)


@pytest.mark.parametrize("name", ["gain", "backlash", "thermal", "compliance", "leadscrew"])
def test_injected_effect_is_recovered_within_its_uncertainty(name, design):
    """Simulate with the effect at a realistic size, fit Model 42 + effect: the true values lie
    within 4.5 reported standard deviations (a joint bound over up to 12 parameters)."""
    design = design.model_copy(update={"platform_mass_kg": 20.0})
    rng = np.random.default_rng(21)
    plan = SessionPlan(temperature_rise_k=5.0)
    truth = perturbed_truth(design, rng, plan)
    values = realistic_values(name, rng, truth)
    meas, _ = simulate_session(
        design, 21, plan, effects=[effect_hook(name, values, truth)], truth=truth
    )
    problem = Problem.build(meas, design, SIG)
    fit = fit_model(problem, ("offset", name), cross_validate=False)
    rows = [p for p in fit.params if p.name.startswith(name + ".")]
    est = np.array([p.value for p in rows])
    sd = np.array([p.sigma for p in rows])
    assert np.all(np.abs(est - values) < 4.5 * sd), (est, values, sd)
    assert all(p.physical for p in rows)


def test_noise_free_effect_fit_is_exact(design):
    design = design.model_copy(update={"platform_mass_kg": 20.0})
    rng = np.random.default_rng(5)
    plan = SessionPlan(noise=NoiseModel(), resolution=None, temperature_rise_k=5.0)
    truth = perturbed_truth(design, rng, plan)
    values = realistic_values("gain", rng, truth)
    meas, _ = simulate_session(
        design, 5, plan, effects=[effect_hook("gain", values, truth)], truth=truth
    )
    fit = fit_model(Problem.build(meas, design, SIG), ("offset", "gain"), cross_validate=False)
    est = np.array([p.value for p in fit.params if p.name.startswith("gain.")])
    assert np.allclose(est, values, atol=1e-6)


def _motion_state_reference(readings: np.ndarray, deadband: float) -> np.ndarray:
    """The definition, pose by pose: a move is a reading more than the dead band from the
    reading at the leg's last move."""
    state = np.zeros_like(readings)
    current = np.zeros(readings.shape[1])
    last = readings[0].copy()
    for m in range(len(readings)):
        step = readings[m] - last
        moved = np.abs(step) > deadband
        current = np.where(moved, np.sign(step), current)
        last = np.where(moved, readings[m], last)
        state[m] = current
    return state


@pytest.mark.parametrize("seed", range(6))
def test_motion_state_follows_its_definition(seed):
    """Runs of moves, still stretches, jitter about the dead band, readings on a coarse grid
    (steps exactly at the dead band): the scan by runs gives the pose-by-pose definition."""
    rng = np.random.default_rng(seed)
    m = int(rng.integers(1, 3000))
    scale = rng.choice([0.001, 0.01, 1.0])
    r = np.cumsum(rng.normal(0, scale, (m, 6)), axis=0)
    # Still stretches (a pose repeats the one before), then jitter on some poses.
    still = rng.random(m) < 0.3
    r = r[np.maximum.accumulate(np.where(still, 0, np.arange(m)))]
    jitter = rng.random(m) < 0.2
    r[jitter] += rng.normal(0, 0.01, (int(jitter.sum()), 6))
    if seed % 2:
        r = np.round(r / 0.01) * 0.01
    for deadband in (0.0, 0.01, 0.02):
        assert np.array_equal(motion_state(r, deadband), _motion_state_reference(r, deadband))
