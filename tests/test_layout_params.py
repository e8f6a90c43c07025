"""The parameter layout of the whole-robot fit: sizes, pack/unpack, and that its blocks are the
columns the refinement and the clamp rows write."""

from __future__ import annotations

import numpy as np
import pytest

from hexcal.estimate.clamp_rows import ClampModel, ClampSteps, Nuisance
from hexcal.estimate.layout import ParameterLayout
from hexcal.estimate.refine import _model, parameter_names, refine
from hexcal.model.noise import NoiseSigmas
from hexcal.sim.session_sim import SessionPlan, simulate_session
from hexcal.sim.simulate import NoiseModel

SIG = NoiseSigmas(0.01, np.deg2rad(0.002), 0.002)
CLEAN = SessionPlan(
    n_type_i=2, n_type_ii=2, n_type_iii=2, n_free=6, noise=NoiseModel(), resolution=None
)


@pytest.mark.parametrize(
    ("model", "q", "n_geometry", "size"),
    [(36, 0, 36, 36), (36, 4, 36, 40), (42, 0, 42, 42), (42, 6, 42, 48)],
)
def test_sizes_for_model_36_and_42_with_and_without_effects(model, q, n_geometry, size):
    lay = ParameterLayout.for_model(model, q)
    assert lay.fit_offsets == (model == 42)
    assert (lay.n_geometry, lay.size) == (n_geometry, size)
    assert lay.a_slice == slice(0, 18) and lay.b_slice == slice(18, 36)
    assert lay.geometry_slice == slice(0, n_geometry)
    assert lay.effects_slice == slice(n_geometry, size)
    assert len(lay.names()) == size
    assert lay.names()[: lay.n_geometry] == parameter_names(model == 42)
    # The blocks present tile the vector, in order.
    cols = np.concatenate([np.arange(size)[s] for s in lay.blocks().values()])
    assert cols.tolist() == list(range(size))
    assert ("offsets" in lay.blocks()) == (model == 42) and ("effects" in lay.blocks()) == bool(q)
    assert ParameterLayout.of_vector(np.zeros(size), model == 42) == lay


def test_model_36_has_no_offset_block():
    lay = ParameterLayout.for_model(36)
    with pytest.raises(ValueError, match="offsets"):
        _ = lay.offsets_slice
    with pytest.raises(ValueError, match="fixed"):
        lay.offsets(np.zeros(36))
    fixed = np.arange(6.0)
    assert lay.offsets(np.zeros(36), fixed) is fixed
    with pytest.raises(ValueError):
        ParameterLayout.for_model(40)
    with pytest.raises(ValueError):
        ParameterLayout.of_vector(np.zeros(30), False)


@pytest.mark.parametrize(("fit_offsets", "q"), [(False, 0), (False, 3), (True, 0), (True, 3)])
def test_pack_and_unpack_round_trip(fit_offsets, q):
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(6, 3)), rng.normal(size=(6, 3))
    off, theta = rng.normal(size=6), rng.normal(size=q)
    lay = ParameterLayout(fit_offsets, q)
    x = lay.pack(a, b, off, theta)
    assert x.shape == (lay.size,)
    # The same vector as concatenating by hand, bit for bit.
    by_hand = np.concatenate([a.ravel(), b.ravel()] + ([off] if fit_offsets else []) + [theta])
    assert x.tobytes() == by_hand.tobytes()
    assert lay.a(x).shape == (6, 3) and np.array_equal(lay.a(x), a)
    assert np.array_equal(lay.b(x), b)
    assert np.array_equal(lay.offsets(x, np.zeros(6)), off if fit_offsets else np.zeros(6))
    assert np.array_equal(lay.effects(x), theta)
    # Views, not copies; and the round trip back to the vector.
    assert np.shares_memory(lay.a(x), x) and np.shares_memory(lay.b(x), x)
    assert not q or np.shares_memory(lay.effects(x), x)
    again = lay.pack(lay.a(x), lay.b(x), lay.offsets(x, off), lay.effects(x))
    assert again.tobytes() == x.tobytes()
    # Per-leg columns agree with the blocks.
    for k in range(6):
        assert np.array_equal(x[lay.a_of_leg(k)], a[k]) and np.array_equal(x[lay.b_of_leg(k)], b[k])
        assert [lay.a_column(k, c) for c in range(3)] == list(range(18))[lay.a_of_leg(k)]
        assert [lay.b_column(k, c) for c in range(3)] == list(range(36))[lay.b_of_leg(k)]
        if fit_offsets:
            assert x[lay.offset_column(k)] == off[k]
    # A batch (..., p) unpacks to (..., 6, 3).
    assert lay.a(np.stack([x, x])).shape == (2, 6, 3)


def test_pack_refuses_what_does_not_fit():
    with pytest.raises(ValueError, match="offsets"):
        ParameterLayout(True).pack(np.zeros((6, 3)), np.zeros((6, 3)))
    with pytest.raises(ValueError, match="effect"):
        ParameterLayout(False, 2).pack(np.zeros((6, 3)), np.zeros((6, 3)), effects=np.zeros(3))
    with pytest.raises(ValueError, match=r"\(6, 3\)"):
        ParameterLayout(False).pack(np.zeros((5, 3)), np.zeros((6, 3)))
    # Offsets given to a layout that does not fit them are left out; θ defaults to zeros.
    x = ParameterLayout(False, 2).pack(np.ones((6, 3)), np.ones((6, 3)), np.ones(6))
    assert x.shape == (38,) and not x[36:].any()


@pytest.mark.parametrize("fit_offsets", [True, False])
def test_the_blocks_are_the_columns_refine_uses(design, fit_offsets):
    """The refinement's Jacobian writes a, b, the offsets and θ in the layout's columns, and its
    result unpacks through the same layout."""
    meas, truth = simulate_session(design, 11, CLEAN)
    P, R, rho = meas.position, meas.rotations.as_matrix(), meas.readings
    q = 2
    basis = np.random.default_rng(1).normal(size=(len(P), 6, q))
    lay = ParameterLayout(fit_offsets, q)
    x = lay.pack(truth.a, truth.b, truth.offsets, [0.1, -0.2])
    _, jac = _model(x, P, R, rho, truth.offsets, fit_offsets, basis)
    assert jac.shape == (len(P), 6, lay.size)
    for k in range(6):
        others = [j for j in range(6) if j != k]
        for cols in (lay.a_of_leg(k), lay.b_of_leg(k)):
            assert jac[:, k, cols].any() and not jac[:, others, cols].any()
        if fit_offsets:
            assert (jac[:, k, lay.offset_column(k)] == -1.0).all()
            assert not jac[:, others, lay.offset_column(k)].any()
    assert np.array_equal(jac[:, :, lay.effects_slice], -basis)

    ref = refine(P, R, rho, truth.a, truth.b, truth.offsets, fit_offsets, SIG, basis=basis)
    assert ref.layout == lay and ref.names == lay.names()
    assert np.array_equal(ref.a, ref.x[:18].reshape(6, 3))
    assert np.array_equal(ref.b, ref.x[18:36].reshape(6, 3))
    fixed = truth.offsets + 1.0
    assert np.array_equal(ref.offsets(fixed), ref.x[36:42] if fit_offsets else fixed)
    assert np.array_equal(lay.effects(ref.x), ref.x[36 + 6 * fit_offsets :])
    cov_a = ref.cov[lay.a_slice, lay.a_slice]
    assert np.array_equal(cov_a, ref.cov[:18, :18])


def test_the_clamp_rows_use_the_same_columns(design):
    """The clamp model's parameter vector is the layout's, then the steps' nuisance."""
    meas, truth = simulate_session(design, 11, CLEAN)
    P, R, rho = meas.position, meas.rotations.as_matrix(), meas.readings
    steps = ClampSteps.from_table(meas.leg, meas.constraint, meas.step)
    nu = Nuisance.seed(steps, truth.a, truth.b, P, R)
    model = ClampModel(steps, P, R, rho, truth.offsets, True, np.zeros((len(P), 6, 0)), nu.u)
    lay = model.layout
    assert lay == ParameterLayout.for_model(42)
    x = np.concatenate([lay.pack(truth.a, truth.b, truth.offsets), model.nuisance_vector(nu)])
    _, jac, _ = model.evaluate(x, want_jz=False)
    _, jl = _model(x[: lay.size], P, R, rho, truth.offsets, True)
    free = meas.constraint == "free"
    assert np.array_equal(jac[free, :6, : lay.size], jl[free])
    with pytest.raises(ValueError, match="entries"):
        model.evaluate(x[:-1])
