"""The simulator: constraints hold exactly, limits respected, noise of the stated size, effects
inverted exactly."""

from __future__ import annotations

import numpy as np

from hexcal.sim.session_sim import SessionPlan, simulate_session
from hexcal.sim.simulate import Limits, NoiseModel, PoseContext, Simulator

K = 2


def _legs(sim, P, R):
    v = P[..., None, :] + np.einsum("...ij,kj->...ki", R, sim.robot.b) - sim.robot.a
    return v[..., K, :]


def test_type_constraints_hold(clean_sim, rng):
    v = _legs(clean_sim, *clean_sim.type_i(K, (50,), rng))
    u = v / np.linalg.norm(v, axis=-1, keepdims=True)
    assert np.allclose(u, u[0], atol=1e-12) and np.ptp(np.linalg.norm(v, axis=-1)) > 10
    v = _legs(clean_sim, *clean_sim.type_ii(K, (50,), rng))
    assert np.allclose(v, v[0], atol=1e-10)
    v = _legs(clean_sim, *clean_sim.type_iii(K, (50,), rng))
    length = np.linalg.norm(v, axis=-1)
    assert np.allclose(length, length[0], atol=1e-10) and np.ptp(v[:, 0]) > 5


def test_limits_respected(truth, rng):
    sim = Simulator(
        truth,
        limits=Limits(base_joint_deg=25.0, platform_joint_deg=35.0, reading_range_mm=(40.0, 90.0)),
    )
    P, R = sim.free((500,), rng)
    assert sim.feasible(P, R).all()
    rho = sim.readings(P, R)
    assert rho.min() >= 40.0 and rho.max() <= 90.0


def test_noise_sizes(truth, rng):
    for kind, factor in (("gaussian", 1.0), ("uniform", 1 / np.sqrt(3))):
        sim = Simulator(truth, noise=NoiseModel(0.1, 0.05, 0.02, kind))
        P, R = sim.free((20000,), rng)
        Pm, Rm, rho = sim.measure(rng, P, R)
        assert np.std(Pm - P) == np.float64(np.std(Pm - P))
        assert abs(np.std(Pm - P) / (0.1 * factor) - 1) < _tol(kind, 3 * 20000)
        assert abs(np.std(rho - sim.readings(P, R)) / (0.02 * factor) - 1) < _tol(kind, 6 * 20000)
        dtheta = np.einsum("nji,njk->nik", R, Rm)  # Rᵀ R_meas = exp([dθ]x)
        angle = np.array([dtheta[:, 2, 1], dtheta[:, 0, 2], dtheta[:, 1, 0]])
        assert abs(np.std(angle) / (np.deg2rad(0.05) * factor) - 1) < _tol(kind, 3 * 20000)


def _tol(kind: str, n: int) -> float:
    """4σ of a standard deviation estimated from n draws: its relative σ is √((κ − 1)/(4n))
    with κ the kurtosis (3 Gaussian, 9/5 uniform): the sample variance's spread (μ₄ − σ⁴)/n,
    halved for the square root."""
    kurtosis = 3.0 if kind == "gaussian" else 1.8
    return 4 * np.sqrt((kurtosis - 1) / (4 * n))


def test_effect_hook_is_inverted_exactly(truth, rng):
    gain = 0.001

    def encoder_gain(reading, ctx):
        return gain * reading

    sim = Simulator(truth, effects=[encoder_gain])
    P, R = sim.free((20,), rng)
    ctx = PoseContext(P, R, np.arange(20.0), np.full(20, 20.0))
    rho = sim.readings(P, R, ctx)
    assert np.allclose(rho * (1 + gain) + truth.offsets, sim.true_lengths(P, R), atol=1e-11)


def test_session_layout(design):
    meas, _truth = simulate_session(
        design, 9, SessionPlan(n_type_i=3, n_type_ii=4, n_type_iii=5, n_free=6)
    )
    assert len(meas) == 6 * 12 + 6
    assert list(meas.step[:3]) == ["leg1-direction"] * 3
    assert meas.constraint[-1] == "free" and meas.leg[-1] == 0
    assert np.all(np.diff(meas.t) > 0) and meas.temperature is not None
