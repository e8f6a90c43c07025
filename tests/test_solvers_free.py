"""The free-pose linear form: exact on noise-free data, for Model 36 and 42."""

from __future__ import annotations

import pytest
from test_solvers_paper import rel_err

from hexcal.estimate.solvers import free


@pytest.mark.parametrize("k", range(6))
@pytest.mark.parametrize("known_offset", [False, True])
def test_free_linear_noise_free(clean_sim, truth, rng, k, known_offset):
    P, R = clean_sim.free((30,), rng)
    rho = clean_sim.readings(P, R)[:, k]
    b, a, off = free.free_linear(P, R, rho, truth.offsets[k] if known_offset else None)
    assert rel_err(b, truth.b[k]) < 1e-9
    assert rel_err(a, truth.a[k]) < 1e-9
    assert abs(off - truth.offsets[k]) < 1e-9 * truth.offsets[k]
