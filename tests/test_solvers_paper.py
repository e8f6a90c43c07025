"""The seed paper's solvers: noise-free recovery to 1e-9, the printed eq. (5) erratum, and
noisy estimates against their first-order covariance."""

from __future__ import annotations

import numpy as np
import pytest
from statcheck import spread_matches_theory, trace_ratio_tolerance

from hexcal.estimate.solvers import paper
from hexcal.estimate.solvers.linalg import lstsq
from hexcal.sim.simulate import NoiseModel, Simulator

K = 2  # leg 3, as in the paper


def rel_err(est, true):
    return np.max(np.abs(est - true)) / np.max(np.abs(true))


def test_type_i_noise_free(clean_sim, truth, rng):
    P, R = clean_sim.type_i(K, (20, 7), rng)
    length = clean_sim.true_lengths(P, R)[..., K]
    b, a = paper.type_i_paper(P, R, length)
    assert rel_err(b, truth.b[K]) < 1e-9
    assert rel_err(a, truth.a[K]) < 1e-9


def test_printed_eq5_sign_is_wrong(clean_sim, truth, rng):
    """As printed, the a-block (ρ_i − ρ_{i+1}) I returns −a_k: the paper's eq. (5) erratum."""
    P, R = clean_sim.type_i(K, (5, 7), rng)
    length = clean_sim.true_lengths(P, R)[..., K]
    x = lstsq(*paper.eq5_system(P, R, length, printed=True))
    assert rel_err(x[..., 3:], -truth.a[K]) < 1e-9
    assert np.min(np.linalg.norm(x[..., 3:] - truth.a[K], axis=-1)) > 100.0


def test_type_ii_noise_free(clean_sim, truth, rng):
    P, R = clean_sim.type_ii(K, (20, 4), rng)
    assert rel_err(paper.type_ii_paper(P, R), truth.b[K]) < 1e-9


def test_type_iii_and_offset_noise_free(clean_sim, truth, rng):
    P, R = clean_sim.type_iii(K, (20, 5), rng)
    a = paper.type_iii_paper(P, R, np.broadcast_to(truth.b[K], (20, 3)))
    assert rel_err(a, truth.a[K]) < 1e-9
    rho = clean_sim.readings(P, R)[..., K]
    off = paper.offset_eq19(P, R, np.broadcast_to(truth.b[K], (20, 3)), a, rho)
    assert np.max(np.abs(off - truth.offsets[K])) < 1e-9 * truth.offsets[K]


@pytest.mark.parametrize("method", ["type_i", "type_ii", "type_iii"])
def test_noisy_spread_matches_first_order_theory(method, truth, rng):
    """Monte-Carlo covariance of each solver against its delta-method prediction, and no bias
    beyond 4 standard errors of the Monte-Carlo mean."""
    sim = Simulator(truth, noise=NoiseModel(0.01, 0.002, 0.002))
    P0, R0 = getattr(sim, method)(K, (8,), rng)

    def solve(P, R, rho):
        if method == "type_i":
            return np.concatenate(paper.type_i_paper(P, R, rho + truth.offsets[K]), axis=-1)
        if method == "type_ii":
            return paper.type_ii_paper(P, R)
        return paper.type_iii_paper(P, R, np.broadcast_to(truth.b[K], (*P.shape[:-2], 3)))

    trials = 4000
    ratio, mean, mc = spread_matches_theory(sim, solve, P0, R0, K, trials, rng)
    assert abs(ratio - 1.0) < trace_ratio_tolerance(trials), ratio
    true = {
        "type_i": np.concatenate([truth.b[K], truth.a[K]]),
        "type_ii": truth.b[K],
        "type_iii": truth.a[K],
    }[method]
    assert np.all(np.abs(mean - true) < 4 * np.sqrt(np.diag(mc) / trials) + 1e-12)
