"""The clamps' constraints in the whole-robot fit: their rows and derivatives, exactness on clean
data, and the estimator against the Cramér–Rao bound of the full likelihood."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hexcal.estimate.clamp_rows import ROWS, ClampModel, ClampSteps, Nuisance
from hexcal.estimate.layout import ParameterLayout
from hexcal.estimate.refine import refine
from hexcal.model.noise import NoiseSigmas
from hexcal.sim.session_efficiency import BLOCKS, fisher_bound, session_efficiency
from hexcal.sim.session_sim import SessionPlan, simulate_session
from hexcal.sim.simulate import NoiseModel

SIG = NoiseSigmas(0.01, np.deg2rad(0.002), 0.002)
CLEAN = SessionPlan(
    n_type_i=4, n_type_ii=4, n_type_iii=4, n_free=6, noise=NoiseModel(), resolution=None
)


def _session(design, seed=11, plan=CLEAN):
    meas, truth = simulate_session(design, seed, plan)
    steps = ClampSteps.from_table(meas.leg, meas.constraint, meas.step)
    return meas, truth, steps


def test_steps_group_poses_by_step_leg_and_constraint():
    leg = [3, 3, 3, 0, 3, 3, 2]
    con = ["direction", "direction", "length", "free", "direction", "length", "direction+length"]
    step = ["s1", "s1", "s2", "free", "s3", "s2", "s4"]
    steps = ClampSteps.from_table(leg, con, step)
    assert steps.group.tolist() == [0, 0, 1, -1, 2, 1, 3]
    assert steps.leg.tolist() == [2, 2, 2, 1]
    assert steps.kind == ("direction", "length", "direction", "direction+length")
    assert steps.n_nuisance == 2 + 1 + 2 + 3
    assert steps.nuisance_names[:3] == ["s1:u.t1", "s1:u.t2", "s2:r"]
    # Without a step column, one clamp per leg and constraint (as the linear methods assume).
    assert ClampSteps.from_table(leg, con).group.tolist() == [0, 0, 1, -1, 0, 1, 2]


def test_rows_in_use_per_constraint(design):
    meas, truth, steps = _session(design)
    nu = Nuisance.seed(steps, truth.a, truth.b, meas.position, meas.rotations.as_matrix())
    model = ClampModel(steps, meas.position, meas.rotations.as_matrix(), meas.readings,
                       truth.offsets, True, np.zeros((len(meas), 6, 0)), nu.u)  # fmt: skip
    per_pose = model.mask.sum(axis=1)
    expected = {"direction": 8, "direction+length": 9, "length": 7, "free": 6}
    for c, n in expected.items():
        assert set(per_pose[meas.constraint == c]) == {n}, c
    # A direction-clamped pose drops its own leg's length row (contained in the clamp's rows).
    i = np.where(meas.constraint == "direction")[0][0]
    assert not model.mask[i, meas.leg[i] - 1]
    assert model.mask.shape == (len(meas), ROWS)


@pytest.mark.parametrize("fit_offsets", [True, False])
def test_derivatives_match_finite_differences(design, fit_offsets):
    """Parameter Jacobian (geometry, offsets, effect θ, nuisance) and measurement Jacobian
    (position, body-frame rotation, readings) against central differences."""
    meas, truth, steps = _session(design)
    P, R, rho = meas.position, meas.rotations.as_matrix(), meas.readings
    rng = np.random.default_rng(1)
    basis = rng.normal(size=(len(P), 6, 2))
    nu = Nuisance.seed(steps, truth.a, truth.b, P, R)
    model = ClampModel(steps, P, R, rho, truth.offsets, fit_offsets, basis, nu.u + 0.01)
    assert model.layout == ParameterLayout(fit_offsets, 2)
    x = np.concatenate(
        [
            model.layout.pack(truth.a, truth.b, truth.offsets, [0.1, -0.2]),
            model.nuisance_vector(nu) + rng.normal(0, 0.01, steps.n_nuisance),
        ]
    )
    res, jac, jz = model.evaluate(x)
    assert not res[~model.mask].any() and not jac[~model.mask].any()
    h = 1e-6
    num = np.stack(
        [
            (model.evaluate(x + h * e)[0] - model.evaluate(x - h * e)[0]) / (2 * h)
            for e in np.eye(len(x))
        ],
        axis=-1,
    )
    assert np.abs(num - jac).max() < 1e-6 * np.abs(jac).max()

    def at(d):  # d (12,): position, body-frame rotation, readings
        Rp = R @ Rotation.from_rotvec(d[3:6]).as_matrix()
        m = ClampModel(
            steps, P + d[:3], Rp, rho + d[6:], truth.offsets, fit_offsets, basis, nu.u + 0.01
        )
        return m.evaluate(x)[0]

    for c in range(12):
        d = np.zeros(12)
        d[c] = h
        plus, minus = at(d), at(-d)
        assert np.abs((plus - minus) / (2 * h) - jz[..., c]).max() < 1e-6


def test_noise_free_refinement_with_clamps_is_exact(design):
    meas, truth = simulate_session(design, 11, SessionPlan(noise=NoiseModel(), resolution=None))
    steps = ClampSteps.from_table(meas.leg, meas.constraint, meas.step)
    rng = np.random.default_rng(0)
    ref = refine(
        meas.position,
        meas.rotations.as_matrix(),
        meas.readings,
        truth.a + rng.normal(0, 0.5, (6, 3)),
        truth.b + rng.normal(0, 0.5, (6, 3)),
        truth.offsets + 0.5,
        True,
        SIG,
        clamps=steps,
    )
    model42 = ParameterLayout.for_model(42)
    true_x = model42.pack(truth.a, truth.b, truth.offsets)
    assert np.max(np.abs(ref.x - true_x)) < 1e-9 * 200
    assert len(ref.names) == model42.size and ref.cov.shape == (model42.size, model42.size)
    assert ref.residuals.shape == (len(meas), 6)
    # Each step's nuisance value is the clamp's truth: the Type II points are the platform
    # point's position in space.
    nu = ref.clamp_nuisance
    for s, kind in enumerate(steps.kind):
        if kind == "direction+length":
            k, m = steps.leg[s], steps.group == s
            p = meas.position[m] + meas.rotations.as_matrix()[m] @ truth.b[k]
            assert np.allclose(nu.C[s], p, atol=1e-9)


def test_the_refinement_reports_the_cramer_rao_bound_computed_apart_from_it(design):
    """The clamp-aware refinement's covariance at the truth against the constrained Cramér–Rao
    bound written from the measurement model alone (fisher_bound: every position, orientation
    and reading, the true poses and the clamps' unknowns as parameters, the clamps as
    constraints). Equal to 1e-5 per block's trace (the bound's central differences are good to
    1e-7): a refinement that drops information — the first pose of every clamp step, a clamp
    row — reports a larger covariance and fails. From the leg lengths alone it is larger."""
    plan = SessionPlan(
        n_type_i=5, n_type_ii=5, n_type_iii=5, n_free=20, noise=NoiseModel(), resolution=None
    )
    meas, truth, steps = _session(design, 4, plan)
    P, R, rho = meas.position, meas.rotations.as_matrix(), meas.readings
    crb = fisher_bound(truth, P, R, steps, SIG)
    clamped = refine(P, R, rho, truth.a, truth.b, truth.offsets, True, SIG, clamps=steps)
    lengths = refine(P, R, rho, truth.a, truth.b, truth.offsets, True, SIG)
    for name, sl in BLOCKS.items():
        bound = np.trace(crb[sl, sl])
        assert np.trace(clamped.cov[sl, sl]) / bound == pytest.approx(1.0, abs=1e-5), name
        assert np.trace(lengths.cov[sl, sl]) / bound > 1.2, name


@pytest.mark.slow
@pytest.mark.parametrize(
    ("noise", "trials"),
    [
        (NoiseModel(0.01, 0.002, 0.002), 300),  # a laser tracker and fine encoders
        (NoiseModel(0.1, 0.01, 0.1), 300),  # the noise
    ],
)
def test_session_refinement_reaches_the_bound(design, noise, trials):
    """Whole sessions (5 Type I, 5 Type II, 5 Type III poses per leg, 20 free poses): with the
    clamps' rows the refinement's mean squared error meets the Cramér–Rao bound of the full
    likelihood (fisher_bound, computed apart from the estimator), without bias; from the leg
    lengths alone it wastes most of the platform points' information.

    Spread: the efficiency of a block of 18 coordinates over 300 trials has a Monte-Carlo
    standard error of about 0.03–0.05 (correlated coordinates); ±0.12 is 3σ of it. The bias
    (|mean| / σ of one coordinate) has standard error 1/√300 = 0.058 per coordinate, so the
    largest of 18 stays below 0.2 unless there is a real bias."""
    plan = SessionPlan(n_type_i=5, n_type_ii=5, n_type_iii=5, n_free=20)
    fig = session_efficiency(design, noise, trials=trials, seed=4, plan=plan)
    for block, f in fig["clamps"].items():
        assert abs(f.efficiency - 1.0) < 0.12, (block, f)
        assert f.bias_sigma < 0.2, (block, f)
    assert fig["lengths"]["platform"].efficiency < 0.5
    for block in ("base", "offset"):
        assert fig["lengths"][block].efficiency < fig["clamps"][block].efficiency
