"""Cross-validation folds refitted from the full fit, sharing its work.

Each fold is the fit on the poses outside its test set, started from the full fit's solution
x0 with the pose covariances evaluated there (one pass), as :func:`hexcal.estimate.refine.refine`
with ``passes=1`` would run it. What the folds share is done once:

- the whiteners of every pose at x0;
- the normal equations at x0 (:mod:`hexcal.estimate.leg_rows`), summed over each *cell* — the
  poses that one test set of every partition has in common (5 random × 5 time-blocked folds
  give 25 cells) — so that each fold's first step uses the sum over all cells less its own test
  set's, without evaluating anything.

Each fold then evaluates only its own training poses, and only their gradient, once per
further step (two: it starts next to its optimum, and the normal matrix at the full fit's
solution serves every step, the chord method). The convergence test and the stall guard are
those of :func:`hexcal.estimate.lm.minimise`, which takes over should the steps not shrink.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from hexcal.estimate.layout import ParameterLayout
from hexcal.estimate.leg_rows import LegData, Normal, leg_gradient, leg_normal, pose_precisions
from hexcal.estimate.lm import REL_STEP_TOL, STEP_TOL, minimise, scaled_solve
from hexcal.estimate.refine import MAX_NFEV, FitStalled, _check


def fold_fits(
    d: LegData,
    x0: np.ndarray,
    lay: ParameterLayout,
    sig,
    partitions: list[list[np.ndarray]],
    max_nfev: int | None = None,
) -> list[list[np.ndarray]]:
    """Each fold's parameters (p,), per partition: ``partitions`` are lists of disjoint test
    sets (sorted pose indices) covering the poses of ``d`` (one problem); each fold is fitted on
    the other poses from x0 (p,), with the pose covariances at x0 and the noise ``sig``.
    Raises :class:`~hexcal.estimate.refine.FitStalled` when a fold does not converge."""
    m = d.n_poses
    budget = MAX_NFEV if max_nfev is None else max_nfev
    _, S = pose_precisions(x0[None], d, lay, sig)
    code = np.zeros(m, np.int64)
    for part in partitions:
        label = np.empty(m, np.int64)
        for f, test in enumerate(part):
            label[test] = f
        code = code * len(part) + label
    # The cells: runs of equal code; a stable sort keeps each run's poses in order.
    order = np.argsort(code, kind="stable")
    edges = np.flatnonzero(np.diff(code[order])) + 1
    cells: dict[int, Normal] = {}
    for rows in np.split(order, edges):
        cells[int(code[rows[0]])] = leg_normal(x0[None], d, S, lay, rows)
    total = Normal.zeros(1, lay.size)
    for n in cells.values():
        total += n
    out: list[list[np.ndarray]] = []
    stride = int(np.prod([len(p) for p in partitions]))
    for part in partitions:
        stride //= len(part)
        fits = []
        for f, test in enumerate(part):
            held = Normal.zeros(1, lay.size)
            for c, n in cells.items():
                if (c // stride) % len(part) == f:
                    held += n
            keep = np.ones(m, bool)
            keep[test] = False
            train = np.flatnonzero(keep)
            fits.append(_fold(d.take(train), S[..., train], x0, lay, total - held, budget))
        out.append(fits)
    return out


def _fold(d: LegData, S: np.ndarray, x0: np.ndarray, lay, first: Normal, budget: int):
    """One fold's fit from x0 by the chord method: every step solves with the normal matrix
    at x0 (``first``, known), the gradient evaluated anew at each point (no normal matrix:
    the dearer half of an evaluation). Near x0 the normal matrix barely changes, so the steps
    shrink by orders of magnitude each; the fixed point is where the gradient vanishes, the
    same optimum. Should they stop shrinking, Levenberg–Marquardt takes over from there."""
    A, g, chi2 = first.A, first.g, float(first.chi2[0])
    x = x0[None].copy()
    previous = np.inf
    spent = 1  # the system at x0 counts as the first evaluation
    while spent < budget:
        delta = scaled_solve(A, g, np.zeros(1))
        size = float(np.einsum("bi,bij,bj->b", delta, A, delta)[0])
        if not np.all(np.isfinite(delta)) or size > 0.25 * previous:
            break  # not contracting: the full method from here
        x = x + delta
        if size <= max(STEP_TOL, REL_STEP_TOL * chi2):
            return x[0]
        previous = size
        g, chi2s = leg_gradient(x, d, S, lay)
        spent += 1
        chi2 = float(chi2s[0])
        if not np.isfinite(chi2):
            break
    sol = minimise(partial(_train_normal, d=d, S=S, lay=lay), x, max(budget - spent, 1))
    _check(sol, d, lay, " (a cross-validation fold)")
    return sol.x[0]


def _train_normal(x: np.ndarray, i: np.ndarray, d: LegData, S: np.ndarray, lay) -> Normal:
    return leg_normal(x, d, S, lay)


__all__ = ["FitStalled", "fold_fits"]
