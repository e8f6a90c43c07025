"""Noise propagation to leg lengths: the full 6×6 covariance per pose against Monte-Carlo."""

from __future__ import annotations

import numpy as np

from hexcal.model.noise import NoiseSigmas, leg_covariance
from hexcal.sim.simulate import NoiseModel, Simulator


def test_leg_covariance_matches_monte_carlo(truth, rng):
    sim = Simulator(truth, noise=NoiseModel(0.02, 0.01, 0.003))
    P, R = sim.free((1,), rng)
    trials = 20000
    Pm, Rm, rho = sim.measure(rng, np.repeat(P, trials, 0), np.repeat(R, trials, 0))
    v = Pm[:, None, :] + np.einsum("mij,kj->mki", Rm, truth.b) - truth.a
    res = np.linalg.norm(v, axis=-1) - rho - truth.offsets
    mc = np.cov(res.T)
    sig = NoiseSigmas(0.02, np.deg2rad(0.01), 0.003)
    pred = leg_covariance(truth.a, truth.b, P, R, sig)[0]
    # Entry-wise, a sample covariance from T draws has a standard error ≤ sqrt(2/T)·σ_i σ_j.
    scale = np.sqrt(np.outer(np.diag(pred), np.diag(pred)))
    assert np.all(np.abs(mc - pred) < 5 * np.sqrt(2 / trials) * scale)
    # The legs of one pose are strongly correlated: a diagonal weight would be wrong.
    corr = pred / scale
    assert np.max(np.abs(corr - np.eye(6))) > 0.3
