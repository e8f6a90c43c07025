"""The structured solver of the whole-robot refinement against the dense one it replaced.

The reference here is what hexcal ran before: scipy's MINPACK Levenberg–Marquardt
(``least_squares(method="lm")``) on the dense whitened residual and Jacobian (every pose's six
rows, or nine with a clamp, times every parameter), with the same two covariance passes. The
structured solver (normal equations accumulated pose block by pose block, the steps' nuisance
eliminated by their Schur complement) must reach the same parameters to 1e-9 mm (beyond the
distance at which MINPACK's own tolerance stopped it short of the optimum) and the same
covariance and χ², on the example session and on a simulated 1,000-pose one.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import least_squares

from hexcal.estimate import refine as refine_module
from hexcal.estimate.clamp_normal import Blocked
from hexcal.estimate.clamp_rows import ClampModel, ClampSteps, Nuisance
from hexcal.estimate.layout import ParameterLayout
from hexcal.estimate.leg_rows import BLOCK, LegData, leg_normal, pose_precisions
from hexcal.estimate.lm import minimise, scaled_solve
from hexcal.estimate.model_file import load_robot
from hexcal.estimate.refine import FitStalled, _model, refine
from hexcal.estimate.solvers.whole_robot import calibrate_linear
from hexcal.io.measurements_csv import read_measurements
from hexcal.model.instruments import load_instruments
from hexcal.model.noise import NoiseSigmas, leg_covariance
from hexcal.sim.robots import left_hand
from hexcal.sim.session_sim import SessionPlan, simulate_session, write_session_dir

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "left-hand-sim"
X_TOL_MM = 1e-9


def _lm(fun, jac, x0):
    return least_squares(
        fun, x0, jac=jac, method="lm", xtol=1e-12, ftol=1e-12, gtol=1e-12, x_scale="jac"
    )


def dense_refine(P, R, rho, a0, b0, off0, sig: NoiseSigmas, passes: int = 2):
    """The dense reference: (x (42,), χ², JᵀJ (42, 42)) of Model 42 from the leg lengths."""
    lay = ParameterLayout(True)
    x = lay.pack(a0, b0, off0)
    for _ in range(passes):
        W = np.linalg.inv(np.linalg.cholesky(leg_covariance(lay.a(x), lay.b(x), P, R, sig)))

        def fun(xx, W=W):
            return (W @ _model(xx, P, R, rho, off0, True)[0][..., None]).ravel()

        def jac(xx, W=W):
            return (W @ _model(xx, P, R, rho, off0, True)[1]).reshape(-1, len(xx))

        sol = _lm(fun, jac, x)
        x = sol.x
    jw = jac(x)
    return x, float(sol.fun @ sol.fun), jw.T @ jw


def dense_refine_clamps(P, R, rho, x0, steps: ClampSteps, sig: NoiseSigmas):
    """The dense reference with the clamp rows (one pass, as ``calibrate`` runs it): (x with
    the nuisance, χ²)."""
    lay = ParameterLayout(True)
    nu = Nuisance.seed(steps, lay.a(x0), lay.b(x0), P, R)
    model = ClampModel(steps, P, R, rho, np.zeros(6), True, np.zeros((len(P), 6, 0)), nu.u)
    xf = np.concatenate([x0, model.nuisance_vector(nu)])
    W = model.whiteners(xf, sig.position_mm, sig.orientation_rad, sig.reading_mm)

    def fun(xx):
        res, _, _ = model.evaluate(xx, want_jac=False, want_jz=False)
        return (W @ res[..., None])[..., 0][model.mask]

    def jac(xx):
        return (W @ model.evaluate(xx, want_jz=False)[1])[model.mask]

    sol = _lm(fun, jac, xf)
    return sol.x, float(sol.fun @ sol.fun)


def _example():
    meas = read_measurements(EXAMPLE / "measurements.csv")
    design = load_robot(EXAMPLE / "robot.json")
    sig = NoiseSigmas.from_instruments(load_instruments(EXAMPLE / "instruments.json"))
    return meas, design, sig


def _session_1k(tmp_path):
    """``hexcal simulate --n-free 1000`` (seed 1)."""
    write_session_dir(tmp_path, left_hand(), 1, SessionPlan(n_free=1000))
    meas = read_measurements(tmp_path / "measurements.csv")
    sig = NoiseSigmas.from_instruments(load_instruments(tmp_path / "instruments.json"))
    return meas, load_robot(tmp_path / "robot.json"), sig


def _gn_gap(x, P, R, rho, W) -> float:
    """The largest entry of the Gauss–Newton step at x (mm): how far x is from the optimum."""
    lay = ParameterLayout(True)
    S = np.einsum("mri,mrj->ijm", W, W)[None]  # the precisions, pose axis last
    n = leg_normal(x[None], LegData.of(P, R, rho, np.zeros(6)), S, lay)
    return float(np.max(np.abs(n.step(np.zeros(1)))))


@pytest.mark.parametrize("session", [_example, _session_1k], ids=["example", "1k poses"])
def test_same_fit_as_the_dense_solver(session, tmp_path):
    meas, design, sig = session(tmp_path) if session is _session_1k else session()
    P, R, rho = meas.position, meas.rotations.as_matrix(), meas.readings
    lin = calibrate_linear(P, R, rho, meas.leg, meas.constraint, 42, design.offsets)
    x_ref, chi2_ref, jtj = dense_refine(P, R, rho, lin.a, lin.b, lin.offsets, sig)
    new = refine(P, R, rho, lin.a, lin.b, lin.offsets, True, sig)
    assert new.whiteners is not None
    # MINPACK stops when a step would lower χ² by less than 1e-12 of it (ftol), which can be
    # a few 1e-9 mm short of the optimum (its own Gauss–Newton step there); the structured
    # solver goes on to the optimum. They agree to 1e-9 mm beyond that gap.
    gap = _gn_gap(x_ref, P, R, rho, new.whiteners)
    assert gap < 1e-7
    assert _gn_gap(new.x, P, R, rho, new.whiteners) < 1e-11
    assert np.max(np.abs(new.x - x_ref)) < X_TOL_MM + gap
    assert new.chi2 == pytest.approx(chi2_ref, rel=1e-9)
    assert new.dof == 6 * len(P) - 42
    cov_ref = np.linalg.inv(jtj) * max(1.0, chi2_ref / new.dof)
    scale = np.sqrt(np.outer(np.diag(cov_ref), np.diag(cov_ref)))
    assert np.max(np.abs(new.cov - cov_ref) / scale) < 1e-7
    # The whitened arrays the diagnosis projects with, computed when asked for.
    jw, rw, _ = new.whitened()
    assert jw.shape == (6 * len(P), 42) and rw @ rw == pytest.approx(new.chi2, rel=1e-12)

    steps = ClampSteps.from_table(meas.leg, meas.constraint, meas.step)
    xf_ref, chi2c_ref = dense_refine_clamps(P, R, rho, x_ref, steps, sig)
    clamped = refine(
        P, R, rho, new.a, new.b, new.offsets(design.offsets), True, sig, clamps=steps, passes=1
    )
    assert np.max(np.abs(clamped.x - xf_ref[:42])) < X_TOL_MM
    assert clamped.chi2 == pytest.approx(chi2c_ref, rel=1e-9)


def test_normal_equations_equal_the_dense_ones(design):
    """The compact, blocked accumulation gives the dense JᵀSJ, JᵀSe and χ², with effect columns
    and without fitted offsets alike, over more poses than one block."""
    meas, _ = simulate_session(design, 3, SessionPlan(n_free=BLOCK + 100))
    P, R, rho = meas.position, meas.rotations.as_matrix(), meas.readings
    rng = np.random.default_rng(0)
    sig = NoiseSigmas(0.01, np.deg2rad(0.002), 0.002)
    for fit_offsets in (True, False):
        for q in (0, 4):
            lay = ParameterLayout(fit_offsets, q)
            basis = rng.normal(size=(len(P), 6, q)) if q else None
            x = lay.pack(design.a, design.b, design.offsets, rng.normal(size=q))
            d = LegData.of(P, R, rho, design.offsets, basis)
            W, S = pose_precisions(x[None], d, lay, sig)
            n = leg_normal(x[None], d, S, lay)
            res, jac = _model(x, P, R, rho, design.offsets, fit_offsets, basis)
            jw = (W[0] @ jac).reshape(-1, len(x))
            rw = (W[0] @ res[..., None]).ravel()
            assert np.allclose(n.A[0], jw.T @ jw, rtol=1e-12, atol=1e-12 * np.abs(n.A).max())
            assert np.allclose(n.g[0], jw.T @ rw, rtol=1e-10, atol=1e-10 * np.abs(n.g).max())
            assert n.chi2[0] == pytest.approx(rw @ rw, rel=1e-12)


def test_schur_step_equals_the_full_solve():
    """Eliminating each step's nuisance block gives the step of the whole arrow system."""
    rng = np.random.default_rng(1)
    p, sizes = 8, np.array([2, 3, 1, 3])
    n = p + sizes.sum()
    J = rng.normal(size=(60, n))
    e = rng.normal(size=60)
    start = p
    for s, k in enumerate(sizes):  # rows of other steps do not see this step's unknowns
        J[np.arange(60) % len(sizes) != s, start : start + k] = 0.0
        start += k
    M, g = J.T @ J, J.T @ e
    b = Blocked.zeros(p, sizes)
    b.A[0], b.g[0] = M[:p, :p], g[:p]
    start = p
    for s, k in enumerate(sizes):
        blk = slice(start, start + k)
        b.B[s, :, :k], b.C[s, :k, :k], b.gz[s, :k] = M[:p, blk], M[blk, blk], g[blk]
        start += k
    assert np.allclose(b.full(), M)
    for lam in (0.0, 0.1):
        want = scaled_solve(M[None], g[None], np.array([lam]))[0]
        got = b.step(np.array([lam]))[0]
        assert np.allclose(got, want, rtol=1e-9, atol=1e-12)
        assert b.quad(got[None])[0] == pytest.approx(got @ M @ got, rel=1e-12)


def test_a_batch_finishes_each_problem_on_its_own():
    """Problems of a batch converge independently; a finished one is evaluated no more."""
    rng = np.random.default_rng(2)
    A = rng.normal(size=(3, 5, 4))
    target = rng.normal(size=(3, 4))
    curv = np.array([0.0, 0.5, 3.0])  # the third is the most nonlinear
    seen: list[np.ndarray] = []

    class Quad:
        def __init__(self, x, i):
            r = np.einsum("bij,bj->bi", A[i], x - target[i]) + curv[i, None] * (
                (x - target[i]) ** 2
            ).sum(-1, keepdims=True)
            jac = A[i] + 2 * curv[i, None, None] * (x - target[i])[:, None, :]
            self.A = np.swapaxes(jac, 1, 2) @ jac
            self.g = np.einsum("bji,bj->bi", jac, r)
            self.chi2 = (r**2).sum(-1)

        def take(self, i):
            out = object.__new__(Quad)
            out.A, out.g, out.chi2 = self.A[i], self.g[i], self.chi2[i]
            return out

        def put(self, i, other):
            self.A[i], self.g[i], self.chi2[i] = other.A, other.g, other.chi2

        def step(self, lam):
            return scaled_solve(self.A, self.g, lam)

        def quad(self, d):
            return np.einsum("bi,bij,bj->b", d, self.A, d)

    def evaluate(x, i):
        seen.append(i)
        return Quad(x, i)

    sol = minimise(evaluate, target + 0.3, 200)
    assert sol.converged.all()
    assert np.max(np.abs(sol.x - target)) < 1e-10
    assert sol.nfev[0] < sol.nfev[2]  # the linear one is done first ...
    assert all(0 not in i for i in seen[sol.nfev[0] :])  # ... and left alone since


def test_the_stall_guard_and_a_start_that_is_not_finite(monkeypatch):
    meas, design, sig = _example()
    P, R, rho = meas.position, meas.rotations.as_matrix(), meas.readings
    monkeypatch.setattr(refine_module, "MAX_NFEV", 2)
    with pytest.raises(FitStalled, match="no convergence in 2 evaluations") as stall:
        refine(P, R, rho, design.a, design.b, design.offsets, True, sig)
    assert len(stall.value.rows) == 3
    monkeypatch.undo()
    bad = rho.copy()
    bad[5, 2] = np.nan
    with pytest.raises(FitStalled, match="cannot start"):
        refine(P, R, bad, design.a, design.b, design.offsets, True, sig)
