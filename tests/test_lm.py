"""The batched Levenberg–Marquardt (hexcal.estimate.lm) on small problems whose answers are
known apart from it: linear systems solved by numpy, a rank-deficient one by the
pseudo-inverse, and nonlinear least squares by scipy's ``least_squares``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from scipy.optimize import least_squares

from hexcal.estimate.lm import minimise, scaled_solve


def test_a_batch_of_full_rank_systems_is_solved_each_by_its_own_matrix():
    """Four 4 × 4 systems of different scales (1e-4 … 1e4) in one batch (as many systems as
    unknowns: a batch axis taken for a matrix axis still has the right shape): each δ solves its
    own ``A δ = −g`` as numpy's solver does, to rounding."""
    rng = np.random.default_rng(1)
    A = np.empty((4, 4, 4))
    for b, scale in enumerate((1e-4, 1.0, 30.0, 1e4)):
        m = rng.normal(size=(6, 4)) * rng.uniform(0.5, 3.0, 4)
        A[b] = scale * m.T @ m
    g = rng.normal(size=(4, 4))
    got = scaled_solve(A, g, np.zeros(4))
    want = np.linalg.solve(A, -g[..., None])[..., 0]
    assert np.allclose(got, want, rtol=1e-9, atol=0)


def test_a_rank_deficient_system_moves_only_where_the_data_determine():
    """Two identical columns (the data see only their sum): the step is the pseudo-inverse's
    in the unit-diagonal scaling — its two equal components share the move, and the
    direction the data do not determine (their difference) is left at zero. A batch of two,
    the second well determined and 1e6 times larger, solved exactly beside it."""
    rng = np.random.default_rng(2)
    m = rng.normal(size=(8, 3))
    j = np.column_stack([m[:, 0], m[:, 0], m[:, 1], m[:, 2]])  # columns 0 and 1 alike
    A0 = j.T @ j
    full = rng.normal(size=(8, 4))
    A = np.stack([A0, 1e6 * full.T @ full])
    g = np.stack([j.T @ rng.normal(size=8), rng.normal(size=4)])
    got = scaled_solve(A, g, np.zeros(2))
    d = 1 / np.sqrt(np.diag(A0))
    want0 = d * (np.linalg.pinv(d[:, None] * A0 * d[None, :], rcond=1e-12) @ (-g[0] * d))
    assert np.all(np.isfinite(got))
    assert np.allclose(got[0], want0, rtol=1e-8, atol=1e-12)
    assert got[0, 0] == pytest.approx(got[0, 1], rel=1e-9)
    assert np.allclose(got[1], np.linalg.solve(A[1], -g[1]), rtol=1e-9)


@dataclass
class _Curve:
    """Normal equations of y ≈ a·exp(−b·t) + c for a batch of data sets (the System protocol)."""

    t: np.ndarray  #: (n,)
    y: np.ndarray  #: (B, n)
    chi2: np.ndarray
    A: np.ndarray
    g: np.ndarray

    @classmethod
    def at(cls, t: np.ndarray, y: np.ndarray, x: np.ndarray) -> _Curve:
        a, b, c = x[:, 0, None], x[:, 1, None], x[:, 2, None]
        with np.errstate(over="ignore", invalid="ignore"):  # an overshoot: χ² inf, refused
            e = np.exp(-b * t)
            r = a * e + c - y
            jac = np.stack([e, -a * t * e, np.ones_like(e)], axis=-1)  # (B, n, 3)
            chi2 = np.sum(r**2, axis=-1)
            A = np.einsum("bni,bnj->bij", jac, jac)
            g = np.einsum("bni,bn->bi", jac, r)
        return cls(t, y, chi2, A, g)

    def step(self, lam: np.ndarray) -> np.ndarray:
        return scaled_solve(self.A, self.g, lam)

    def quad(self, delta: np.ndarray) -> np.ndarray:
        return np.einsum("bi,bij,bj->b", delta, self.A, delta)

    def take(self, i: np.ndarray) -> _Curve:
        return _Curve(self.t, self.y[i], self.chi2[i], self.A[i], self.g[i])

    def put(self, i: np.ndarray, other: _Curve) -> None:
        self.chi2[i], self.A[i], self.g[i] = other.chi2, other.A, other.g


def _fit(t: np.ndarray, y: np.ndarray, x0: np.ndarray, max_nfev: int = 200):
    return minimise(lambda x, i: _Curve.at(t, y[i], x), x0, max_nfev)


def _scipy(t: np.ndarray, y: np.ndarray, x0: np.ndarray) -> np.ndarray:
    def f(x: np.ndarray) -> np.ndarray:
        with np.errstate(over="ignore"):
            return x[0] * np.exp(-x[1] * t) + x[2] - y

    return least_squares(f, x0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15).x


def test_nonlinear_fits_from_far_starts_reach_scipys_optimum():
    """Three data sets (a clean decay, a noisy one, one the model misfits by far: a sine
    added), each from a start where the first Gauss–Newton steps overshoot (b 20× too large):
    every problem converges, to the optimum scipy's MINPACK finds, to 1e-7 relative."""
    t = np.linspace(0.0, 4.0, 40)
    rng = np.random.default_rng(3)
    clean = 2.0 * np.exp(-1.3 * t) + 0.5
    y = np.stack([clean, clean + rng.normal(0, 0.01, t.size), clean + 0.3 * np.sin(5 * t)])
    x0 = np.tile([1.0, 26.0, 0.0], (3, 1))
    sol = _fit(t, y, x0)
    assert sol.converged.all() and sol.finite.all(), sol.nfev
    for b in range(3):
        want = _scipy(t, y[b], x0[b])
        assert np.allclose(sol.x[b], want, rtol=1e-7, atol=1e-9), (b, sol.x[b], want)
    assert np.allclose(sol.x[0], [2.0, 1.3, 0.5], rtol=1e-9)


def test_a_problem_out_of_evaluations_is_not_converged_and_does_not_hold_the_others():
    """max_nfev too small for a far start: that problem reports not converged, while a
    problem started at its optimum converges in the same batch."""
    t = np.linspace(0.0, 4.0, 40)
    clean = 2.0 * np.exp(-1.3 * t) + 0.5
    y = np.stack([clean, clean])
    x0 = np.array([[1.0, 26.0, 0.0], [2.0, 1.3, 0.5]])
    sol = _fit(t, y, x0, max_nfev=3)
    assert list(sol.converged) == [False, True]
    assert sol.nfev[0] == 3
    assert np.allclose(sol.x[1], [2.0, 1.3, 0.5], rtol=1e-12)


@dataclass
class _Noise:
    """A System whose χ² the steps cannot change (every point evaluates to ``chi2``, as a fit
    whose steps are below what χ² resolves): the step from x is ``−shrink·(x − target)``
    (``shrink`` 1: the steps go straight to ``target``; a ``target`` moved with x: steps of a
    constant length, the rounding noise of a fit at its floor), and δᵀAδ = ``a``·‖δ‖²."""

    x: np.ndarray  #: (B, n)
    chi2: np.ndarray  #: (B,)
    a: float
    target: np.ndarray  #: (B, n)
    shrink: np.ndarray  #: (B, 1)

    def step(self, lam: np.ndarray) -> np.ndarray:
        return -self.shrink * (self.x - self.target) / (1.0 + lam[:, None])

    def quad(self, delta: np.ndarray) -> np.ndarray:
        return self.a * np.sum(delta**2, axis=-1)

    def take(self, i: np.ndarray) -> _Noise:
        return _Noise(self.x[i], self.chi2[i], self.a, self.target[i], self.shrink[i])

    def put(self, i: np.ndarray, other: _Noise) -> None:
        self.x[i], self.chi2[i], self.target[i] = other.x, other.chi2, other.target
        self.shrink[i] = other.shrink


def test_a_step_below_the_relative_tolerance_of_a_huge_chi2_is_the_last_without_evaluation():
    """A model that misfits by far (χ² = 1e20): a Gauss–Newton step removing 10 of it (above
    STEP_TOL, below REL_STEP_TOL · χ² = 100) is the last, taken without another evaluation —
    one evaluation in all, at x0."""
    x0 = np.array([[1.0]])
    sol = minimise(
        lambda x, i: _Noise(x.copy(), np.full(len(i), 1e20), 10.0, x + 1.0, np.ones((len(i), 1))),
        x0,
        50,
    )
    assert sol.converged.all() and list(sol.nfev) == [1]
    assert sol.x[0, 0] == 2.0


def test_steps_at_the_rounding_floor_stop_when_they_stop_shrinking():
    """χ² = 1e6 that the steps cannot lower, and steps of δᵀAδ = 1e-5 (above STEP_TOL and
    REL_STEP_TOL · χ², below UNRESOLVED · χ² = 1e-3): the rounding floor. Problem 0's steps keep
    their length (each one from the point the last reached) and its χ² rises by 1e-15 of itself
    per step, as rounding may: the first step is taken all the same (too small for χ² to judge),
    and the second, no shorter than half the first, is the last — two evaluations, both steps
    taken (x0 + 2 δ). Problem 1 (χ² = 1e3: REL_STEP_TOL · χ² = 1e-15, below STEP_TOL): its
    steps shrink fourfold in length each time (δᵀAδ sixteenfold), so they are not at the floor
    and it goes on to STEP_TOL (1e-5 · 16⁻ᵏ ≤ 1e-12 at k = 6, the seventh evaluation)."""

    def evaluate(x: np.ndarray, i: np.ndarray) -> _Noise:
        first = i[:, None] == 0
        target = np.where(first, x + 1e-3, 0.0)  # problem 0: always a step of 1e-3 ahead
        shrink = np.where(first, 1.0, 0.75)
        # Problem 0: χ² rising by rounding; problem 1: a smaller χ², REL_STEP_TOL · χ² = 1e-15
        chi2 = np.where(first[:, 0], 1e6 + 1e-6 * (x[:, 0] - 5.0), 1e3)
        return _Noise(x.copy(), chi2, 10.0, target, shrink)

    x0 = np.array([[5.0], [1e-3 / 0.75]])  # problem 1's first step: 0.75 of the way to 0
    sol = minimise(evaluate, x0, 50)
    assert sol.converged.all(), sol.nfev
    assert list(sol.nfev) == [2, 7]
    assert sol.x[0, 0] == pytest.approx(5.0 + 2e-3, rel=1e-15)
    assert abs(sol.x[1, 0]) < 1e-6


def test_the_rank_cut_is_relative_to_each_problems_own_largest_eigenvalue():
    """Two 2 × 2 systems of unit diagonal: the first nearly singular (scaled eigenvalues 2 and
    2e-15, a relative 1e-15 below RANK_TOL, so its weak direction is left out), the second with
    eigenvalues 1.99 and 0.01. Each problem's cut is relative to its own largest eigenvalue:
    the first's step is the pseudo-inverse's along its strong direction only, however small
    the second's eigenvalues are."""
    c = 1.0 - 2e-15
    A = np.array([[[1.0, c], [c, 1.0]], [[1.0, 0.99], [0.99, 1.0]]])
    g = np.array([[1.0, -0.5], [0.3, 0.2]])
    got = scaled_solve(A, g, np.zeros(2))
    strong = np.array([1.0, 1.0]) / np.sqrt(2.0)  # the eigenvector of 2 − 2e-15·…
    want0 = -strong * (strong @ g[0]) / (1.0 + c)
    assert np.allclose(got[0], want0, rtol=1e-9, atol=0)
    assert np.allclose(got[1], np.linalg.solve(A[1], -g[1]), rtol=1e-9)


@dataclass
class _Scripted:
    """One problem whose χ² at each evaluation is the next of a script, whatever the point: a
    step is a success or a failure as the script says. Its steps (δ = 1, δᵀAδ = 1: never
    negligible) record the λ they are asked for."""

    chi2: np.ndarray
    asked: list

    def step(self, lam: np.ndarray) -> np.ndarray:
        self.asked.append(float(lam[0]))
        return np.ones((len(lam), 1))

    def quad(self, delta: np.ndarray) -> np.ndarray:
        return np.sum(delta**2, axis=-1)

    def take(self, i: np.ndarray) -> _Scripted:
        return _Scripted(self.chi2[i].copy(), self.asked)

    def put(self, i: np.ndarray, other: _Scripted) -> None:
        self.chi2[i] = other.chi2


def test_lambda_grows_tenfold_per_failure_shrinks_tenfold_per_success_and_returns_to_zero():
    """Gauss–Newton (λ = 0) until a step fails to lower χ²; then λ = 1e-3, ×10 per failure,
    ÷10 per success, and back to 0 once it would fall below 1e-12."""
    script = [100.0, 200.0, 150.0, 90.0, 80.0, 85.0] + [79.0 - k for k in range(11)]
    asked: list[float] = []
    calls = iter(script)

    def evaluate(x: np.ndarray, i: np.ndarray) -> _Scripted:
        return _Scripted(np.array([next(calls)]), asked)

    sol = minimise(evaluate, np.zeros((1, 1)), len(script))
    assert not sol.converged[0] and sol.nfev[0] == len(script)
    # fail, fail, success, success, fail, then ten successes (1e-3 → 1e-12, then 0)
    want = [0.0, 1e-3, 1e-2, 1e-3, 1e-4, 1e-3] + [10.0**-k for k in range(4, 13)] + [0.0]
    assert asked[: len(want)] == pytest.approx(want, rel=1e-9, abs=0)
    assert sol.x[0, 0] == 13.0  # the 13 steps that lowered χ² taken, the 3 that failed not
