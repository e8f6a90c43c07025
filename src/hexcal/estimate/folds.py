"""Cross-validation folds refitted from the full fit, sharing its work.

Each fold is the fit on the poses outside its test set, started from the full fit's solution
x0 with the pose covariances evaluated there (one pass), as :func:`hexcal.estimate.refine.refine`
with ``passes=1`` would run it. What the folds share is done once:

- the whiteners of every pose at x0;
- the normal equations at x0 (:mod:`hexcal.estimate.leg_rows`), summed over each *cell* — the
  poses that one test set of every partition has in common (5 random × 5 time-blocked folds
  give 25 cells) — so that each fold's first step uses the sum over all cells less its own test
  set's, without evaluating anything.

Each fold then evaluates only its own training poses, once per further step (one or two: it
starts next to its optimum). The steps, the convergence test and the stall guard are those of
:func:`hexcal.estimate.lm.minimise`.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from hexcal.estimate.layout import ParameterLayout
from hexcal.estimate.leg_rows import LegData, Normal, leg_normal, pose_precisions
from hexcal.estimate.lm import minimise
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
    _, S = pose_precisions(x0[None], d, lay, sig)
    code = np.zeros(m, np.int64)
    for part in partitions:
        label = np.empty(m, np.int64)
        for f, test in enumerate(part):
            label[test] = f
        code = code * len(part) + label
    cells: dict[int, Normal] = {}
    for c in np.unique(code):
        cells[int(c)] = leg_normal(x0[None], d, S, lay, np.flatnonzero(code == c))
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
            train = np.setdiff1d(np.arange(m), test)
            dt, St = d.take(train), S[..., train]
            sol = minimise(
                partial(_train_normal, d=dt, S=St, lay=lay),
                x0[None],
                MAX_NFEV if max_nfev is None else max_nfev,
                first=total - held,
            )
            _check(sol, dt, lay, " (a cross-validation fold)")
            fits.append(sol.x[0])
        out.append(fits)
    return out


def _train_normal(x: np.ndarray, i: np.ndarray, d: LegData, S: np.ndarray, lay) -> Normal:
    return leg_normal(x, d, S, lay)


__all__ = ["FitStalled", "fold_fits"]
