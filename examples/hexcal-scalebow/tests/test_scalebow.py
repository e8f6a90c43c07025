"""The scalebow effect honours hexcal's Effect API, is loaded through its entry point, and is
fitted back from a simulated session hiding it."""

from __future__ import annotations

from importlib.metadata import entry_points

import numpy as np
import pytest

from hexcal.effects import CATALOGUE, EffectData, get_effect
from hexcal.estimate.effect_fit import Problem, fit_model
from hexcal.model.noise import NoiseSigmas
from hexcal.sim.inject import effect_hook, realistic_values
from hexcal.sim.robots import left_hand
from hexcal.sim.session_sim import SessionPlan, perturbed_truth, simulate_session
from hexcal.sim.simulate import NoiseModel

SIG = NoiseSigmas(0.01, np.deg2rad(0.002), 0.002)


def test_the_entry_point_is_declared_and_hexcal_loaded_it():
    (ep,) = [e for e in entry_points(group="hexcal.effects") if e.name == "scalebow"]
    assert ep.value == "hexcal_scalebow:ScaleBow"
    eff = CATALOGUE["scalebow"]  # loaded when hexcal.effects was imported
    assert eff.source.kind == "package"
    assert (eff.source.package, eff.source.version) == ("hexcal-scalebow", "0.1.0")


def test_contract():
    design = left_hand()
    eff = get_effect("scalebow")
    specs = eff.params(design)
    assert [s.name for s in specs] == [f"scalebow.q{k}" for k in range(1, 7)]
    assert all(s.unit == "µm" and s.resolution == 4.0 for s in specs)
    rng = np.random.default_rng(1)
    meas, truth = simulate_session(design, 1, SessionPlan(n_free=10))
    r = meas.rotations.as_matrix()
    data = EffectData(meas.readings, meas.position, r, meas.t, None, truth, truth.a, truth.b)
    basis = eff.basis(data)
    assert basis.shape == (len(meas), 6, 6)
    # Each leg's column is its own: the quadratic of its reading's distance from home, in mm/µm.
    assert np.allclose(basis[:, 0, 1:], 0.0) and (basis[:, 0, 0] >= 0).all()
    values = eff.typical_values(rng, truth)
    assert values.shape == (6,) and (np.abs(values) >= 5).all() and (np.abs(values) <= 15).all()


def test_robot_json_priors_apply_without_the_effect_asking():
    robot = left_hand().model_copy(update={"plausible": {"scalebow": [-30.0, 30.0]}})
    assert get_effect("scalebow").params(robot)[0].plausible == (-30.0, 30.0)


@pytest.mark.parametrize("noise", [False, True])
def test_a_hidden_bow_is_fitted_back(noise):
    """Noise-free, the fit is exact; with the standard noise, within 4.5 standard deviations."""
    design = left_hand()
    rng = np.random.default_rng(4)
    plan = SessionPlan() if noise else SessionPlan(noise=NoiseModel(), resolution=None)
    truth = perturbed_truth(design, rng, plan)
    values = realistic_values("scalebow", rng, truth)
    meas, _ = simulate_session(
        design, 4, plan, effects=[effect_hook("scalebow", values, truth)], truth=truth
    )
    fit = fit_model(Problem.build(meas, design, SIG), ("offset", "scalebow"), cross_validate=False)
    rows = [p for p in fit.params if p.name.startswith("scalebow.")]
    est = np.array([p.value for p in rows])
    if noise:
        sd = np.array([p.sigma for p in rows])
        assert np.all(np.abs(est - values) < 4.5 * sd), (est, values, sd)
    else:
        assert np.allclose(est, values, atol=1e-4)
