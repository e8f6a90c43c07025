"""Direct linear forms (beyond the paper): noise-free recovery and first-order spread."""

from __future__ import annotations

import numpy as np
import pytest
from statcheck import spread_matches_theory, trace_ratio_tolerance
from test_solvers_paper import K, rel_err

from hexcal.estimate.solvers import direct
from hexcal.sim.simulate import NoiseModel, Simulator


def test_type_i_direct_noise_free(clean_sim, truth, rng):
    P, R = clean_sim.type_i(K, (20, 5), rng)
    length = clean_sim.true_lengths(P, R)[..., K]
    b, a, u = direct.type_i_direct(P, R, length)
    assert rel_err(b, truth.b[K]) < 1e-9 and rel_err(a, truth.a[K]) < 1e-9
    assert np.allclose(np.linalg.norm(u, axis=-1), 1.0, atol=1e-12)


def test_type_i_model42_confounds_base_point_and_offset(clean_sim, truth, rng):
    """With the direction clamped, only a + Δ·u is determined: the offset slides along the leg."""
    P, R = clean_sim.type_i(K, (3, 6), rng)
    reading = clean_sim.readings(P, R)[..., K]
    b, u, a_plus = direct.type_i_direct_model42(P, R, reading)
    assert rel_err(b, truth.b[K]) < 1e-9
    assert rel_err(a_plus, truth.a[K] + truth.offsets[K] * u) < 1e-9


def test_type_ii_direct_noise_free(clean_sim, truth, rng):
    P, R = clean_sim.type_ii(K, (20, 4), rng)
    b, c = direct.type_ii_direct(P, R)
    assert rel_err(b, truth.b[K]) < 1e-9
    u, length = clean_sim.home_leg(K)
    assert rel_err(c, truth.a[K] + length * u) < 1e-9


def test_type_iii_sphere_fit_noise_free(clean_sim, truth, rng):
    P, R = clean_sim.type_iii(K, (20, 5), rng)
    a, r = direct.type_iii_direct(P, R, np.broadcast_to(truth.b[K], (20, 3)))
    assert rel_err(a, truth.a[K]) < 1e-9
    assert np.allclose(r, clean_sim.home_leg(K)[1], rtol=1e-9)


@pytest.mark.parametrize("method", ["type_i", "type_ii", "type_iii"])
def test_direct_noisy_spread_matches_first_order_theory(method, truth, rng):
    sim = Simulator(truth, noise=NoiseModel(0.01, 0.002, 0.002))
    P0, R0 = getattr(sim, method)(K, (8,), rng)

    def solve(P, R, rho):
        if method == "type_i":
            b, a, _ = direct.type_i_direct(P, R, rho + truth.offsets[K])
            return np.concatenate([b, a], axis=-1)
        if method == "type_ii":
            return direct.type_ii_direct(P, R)[0]
        return direct.type_iii_direct(P, R, np.broadcast_to(truth.b[K], (*P.shape[:-2], 3)))[0]

    trials = 4000
    ratio, _, _ = spread_matches_theory(sim, solve, P0, R0, K, trials, rng)
    assert abs(ratio - 1.0) < trace_ratio_tolerance(trials), ratio


def test_nested_counts_solve_each_leading_subset(truth, rng):
    """``counts``: the solutions from the first N poses of each set, for every N at once, are
    those of the N poses solved alone (to rounding), for the direct and the paper's forms."""
    from hexcal.estimate.solvers import paper

    sim = Simulator(truth, noise=NoiseModel(0.1, 0.01, 0.1, "uniform"))
    counts = [5, 8, 20]
    P, R = sim.type_i(K, (30, 20), rng)
    P, R, rho = sim.measure(rng, P, R)
    length = rho[..., K] + truth.offsets[K]
    P3, R3 = sim.type_iii(K, (30, 20), rng)
    P3, R3, _ = sim.measure(rng, P3, R3)
    b = np.broadcast_to(truth.b[K], (30, 3))
    nested = {
        "type_i_direct": direct.type_i_direct(P, R, length, counts),
        "type_i_paper": paper.type_i_paper(P, R, length, counts),
        "type_ii_direct": direct.type_ii_direct(P, R, counts),
        "type_ii_paper": (paper.type_ii_paper(P, R, counts),),
        "type_iii_direct": direct.type_iii_direct(P3, R3, b, counts),
        "type_iii_paper": (paper.type_iii_paper(P3, R3, b, counts),),
    }
    for i, n in enumerate(counts):
        alone = {
            "type_i_direct": direct.type_i_direct(P[:, :n], R[:, :n], length[:, :n]),
            "type_i_paper": paper.type_i_paper(P[:, :n], R[:, :n], length[:, :n]),
            "type_ii_direct": direct.type_ii_direct(P[:, :n], R[:, :n]),
            "type_ii_paper": (paper.type_ii_paper(P[:, :n], R[:, :n]),),
            "type_iii_direct": direct.type_iii_direct(P3[:, :n], R3[:, :n], b),
            "type_iii_paper": (paper.type_iii_paper(P3[:, :n], R3[:, :n], b),),
        }
        for name, parts in nested.items():
            for got, want in zip(parts, alone[name], strict=True):
                # 1e-9 mm: rounding of normal equations on mm-sized columns (the noise is 0.1).
                np.testing.assert_allclose(got[:, i], want, rtol=0, atol=1e-9, err_msg=name)
