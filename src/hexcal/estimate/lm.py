"""Levenberg–Marquardt on the normal equations, for a batch of independent problems.

The problems are weighted nonlinear least squares whose normal equations a caller accumulates
(:class:`~hexcal.estimate.leg_rows.Normal`, or :class:`~hexcal.estimate.clamp_normal.Blocked`
when per-step nuisance unknowns are eliminated by their Schur complement). Each iteration
costs one evaluation (residual and normal equations together) at the trial point:

- the step solves ``(Â + λ I) δ̂ = −ĝ`` in the columns scaled to a unit diagonal of A (the
  scaling MINPACK's ``x_scale="jac"`` uses), by Cholesky, falling back on the eigenvectors with
  the directions the data do not determine (relative eigenvalue below :data:`RANK_TOL`) left
  out, so a rank-deficient problem still moves only where it can;
- λ = 0 (Gauss–Newton, converging quadratically near the solution) until a step fails to lower
  χ²; then λ grows tenfold per failure and shrinks tenfold per success, back to 0 (a step
  too small for χ² to resolve, :data:`UNRESOLVED`, is taken as it is);
- a problem has converged when its Gauss–Newton step is negligible: ``δᵀAδ`` (the χ² the step
  would remove, i.e. its length in units of the parameters' standard errors, squared) at most
  :data:`STEP_TOL` (or :data:`REL_STEP_TOL` of χ² when the model misfits by far), or when the
  steps, already too small for χ² to resolve, stop shrinking (the rounding floor). That step
  is taken without another evaluation: the parameters are then within a millionth of a
  standard error of the optimum, and closer still after it;
- or when χ² has not fallen by more than :data:`UNRESOLVED` of itself over :data:`PLATEAU`
  evaluations: a nearly degenerate problem (a scaled eigenvalue of 1e-10, e.g. a spline along
  the legs' inclination that the joints' heights almost absorb) reaches its minimum to
  rounding, where the Gauss–Newton step along the near-null direction is rounding noise
  amplified by 1/eigenvalue and never becomes negligible. The best point is kept, and that
  last step is not taken.

A problem not converged within ``max_nfev`` evaluations, or whose residual stops being finite,
is reported as not converged (the caller raises its own error); the others are not held back
by it. Finished problems leave the batch: only the unfinished ones are evaluated.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, Protocol, TypeVar

import numpy as np

#: A Gauss–Newton step whose δᵀAδ is below this (χ² units) is the last.
STEP_TOL = 1e-12
#: ... or this fraction of χ² when that is larger: a model that misfits by far (χ²/dof in the
#: thousands) converges only linearly, and its rounding floor rises with χ² (measured on the
#: Jugglebot: 1e-26 of χ²).
REL_STEP_TOL = 1e-18
#: Directions of the scaled normal matrix with a relative eigenvalue below this are left out of
#: a step (the data do not determine them).
RANK_TOL = 1e-14
#: A Gauss–Newton step that would lower χ² by less than this fraction of it is taken even when
#: the χ² evaluated after it is not lower: such a change is below what χ² resolves (the
#: residual's rounding, e.g. a 500 mm leg less its reading, is 1e-13 mm, i.e. 1e-12 of χ² or
#: more when the model misfits), while near the optimum the step is reliable.
UNRESOLVED = 1e-9
#: λ after the first failed Gauss–Newton step, and the factor it moves by.
LAMBDA_START = 1e-3
LAMBDA_FACTOR = 10.0
#: λ below this returns to pure Gauss–Newton. Low, so that a problem whose Gauss–Newton step
#: fails in a curved, nearly degenerate valley is damped down to the valley's own eigenvalues
#: (1e-10 of the scaled matrix) before pure Gauss–Newton is tried again: with 1e-7 such a fit
#: cycled between λ = 1e-3 and 0 and took 1,200 evaluations to its minimum instead of 220.
LAMBDA_OFF = 1e-12
#: Evaluations without χ² falling by more than :data:`UNRESOLVED` of itself: the minimum to
#: rounding.
PLATEAU = 12


class System(Protocol):
    """Normal equations of a batch at one point each (see the module doc)."""

    chi2: np.ndarray  #: (B,)

    def step(self, lam: np.ndarray) -> np.ndarray: ...  # (B,) → δ (B, n)

    def quad(self, delta: np.ndarray) -> np.ndarray: ...  # δᵀAδ (B,)

    def take(self, i: np.ndarray) -> System: ...

    def put(self, i: np.ndarray, other) -> None: ...


def scaled_solve(A: np.ndarray, g: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """δ (B, p) solving ``(A + λ diag A) δ = −g`` for A (B, p, p) symmetric, g (B, p), λ (B,),
    in the columns scaled to a unit diagonal; undetermined directions are left out."""
    diag = np.einsum("bii->bi", A)
    d = 1.0 / np.sqrt(np.where(diag > 0, diag, 1.0))
    As = d[:, :, None] * A * d[:, None, :]
    As = As + lam[:, None, None] * np.eye(A.shape[-1])
    gs = -g * d
    try:
        L = np.linalg.cholesky(As)
        # A rank-deficient matrix may factor with a tiny pivot: then use the eigenvectors.
        piv = np.einsum("bii->bi", L)
        if np.all(piv > np.sqrt(RANK_TOL)):
            y = np.linalg.solve(L, gs[..., None])
            return np.linalg.solve(np.swapaxes(L, -1, -2), y)[..., 0] * d
    except np.linalg.LinAlgError:
        pass
    w, V = np.linalg.eigh(As)
    top = np.max(np.abs(w), axis=-1, keepdims=True)
    keep = w > RANK_TOL * np.where(top > 0, top, 1.0)
    inv = np.where(keep, 1.0 / np.where(keep, w, 1.0), 0.0)
    return np.einsum("bij,bj,bkj,bk->bi", V, inv, V, gs) * d


S = TypeVar("S", bound=System)


@dataclass
class Solution(Generic[S]):
    """Where each problem of the batch ended: x (B, n), the system at the last point evaluated
    (whose Gauss–Newton step, negligible, was then taken), evaluations per problem, and whether
    it converged."""

    x: np.ndarray
    system: S
    nfev: np.ndarray
    converged: np.ndarray
    finite: np.ndarray  #: (B,) False where the residual stopped being finite


def minimise(
    evaluate: Callable[[np.ndarray, np.ndarray], S],
    x0: np.ndarray,
    max_nfev: int,
    first: S | None = None,
) -> Solution[S]:
    """Levenberg–Marquardt from x0 (B, n). ``evaluate(x, i)`` returns the :class:`System` of
    the problems ``i`` (indices into the batch) at their points x (len(i), n); ``first``: the
    system at x0 when already known (it counts as an evaluation)."""
    x = np.array(x0, float)
    nb = len(x)
    everyone = np.arange(nb)
    eq = evaluate(x, everyone) if first is None else first
    nfev = np.ones(nb, int)
    finite = np.isfinite(eq.chi2)
    converged = np.zeros(nb, bool)
    active = finite.copy()
    lam = np.zeros(nb)
    previous = np.full(nb, np.inf)  # the last Gauss–Newton step's size, per problem
    level = eq.chi2.copy()  # χ² where the current plateau began, and evaluations since
    flat = np.zeros(nb, int)
    while active.any():
        i = np.flatnonzero(active)
        sub = eq.take(i)
        delta = sub.step(lam[i])
        size = sub.quad(delta)
        gn = lam[i] == 0
        last = gn & (size <= np.maximum(STEP_TOL, REL_STEP_TOL * sub.chi2))
        # At the rounding floor the steps stop shrinking: then the point is the optimum too.
        last |= gn & (size <= UNRESOLVED * np.abs(sub.chi2)) & (size >= 0.5 * previous[i])
        last &= np.all(np.isfinite(delta), axis=-1)
        previous[i] = np.where(gn, size, np.inf)
        x[i[last]] += delta[last]
        converged[i[last]] = True
        active[i[last]] = False
        small = ((lam[i] == 0) & (size <= UNRESOLVED * np.abs(sub.chi2)))[~last]
        go, delta = i[~last], delta[~last]
        spent = nfev[go] >= max_nfev
        active[go[spent]] = False
        go, delta, small = go[~spent], delta[~spent], small[~spent]
        if not len(go):
            break
        trial = x[go] + delta
        new = evaluate(trial, go)
        nfev[go] += 1
        better = np.isfinite(new.chi2) & ((new.chi2 <= eq.chi2[go]) | small)
        ok = go[better]
        x[ok] = trial[better]
        eq.put(ok, new.take(np.flatnonzero(better)))
        lam[ok] = np.where(lam[ok] / LAMBDA_FACTOR < LAMBDA_OFF, 0.0, lam[ok] / LAMBDA_FACTOR)
        bad = go[~better]
        lam[bad] = np.maximum(LAMBDA_START, lam[bad] * LAMBDA_FACTOR)
        fell = eq.chi2[go] < level[go] - UNRESOLVED * np.abs(level[go])
        level[go[fell]] = eq.chi2[go[fell]]
        flat[go] = np.where(fell, 0, flat[go] + 1)
        # A step that cannot lower χ² even when damped to nothing: the point is a minimum to
        # rounding (the Gauss–Newton test above did not see it, e.g. a misfit's huge χ²); or
        # χ² no longer falling beyond rounding (see the module doc).
        stuck = np.r_[bad[lam[bad] > 1e16], go[flat[go] >= PLATEAU]]
        converged[stuck] = True
        active[stuck] = False
    return Solution(x, eq, nfev, converged, finite)
