"""A block of columns scored against a fit in the poses' own terms: the χ² it removes from the
fit's residual in-sample and on held-out poses, the model's own parameters projected out,
without whitening and projecting the columns row by row.

A basis B (M, 6, p) of leg-length columns whitens to W = −w B pose by pose (w the pose's 6×6
whitener, :func:`hexcal.diagnosis.scoring.whitened_columns`), and everything the score needs
— WᵀW, Wᵀr and qᵀW, q an orthonormal basis of the fit's whitened Jacobian — is a sum over the
poses of B's rows against a per-pose matrix made once per fit (C = wᵀw, d = wᵀr, A = wᵀq):
M·p² work where the rows would cost 6M·p·(p + rank). A fold's products are the same sums over
its poses; a suffix of the poses' (a step from a pose on) is their cumulative sum. The covariate
explorer (:mod:`hexcal.diagnosis.explorer`) and the frame-step search
(:mod:`hexcal.diagnosis.frame_search`) score through here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from hexcal.diagnosis.scoring import jacobian_basis
from hexcal.estimate.effect_fit import ModelFit

#: Folds of whole poses of the held-out score.
K_FOLDS = 5


def solve(g: np.ndarray, b: np.ndarray) -> np.ndarray:
    """G⁺b for a Gram matrix G: by Cholesky, or the pseudo-inverse where G is singular (two
    columns the same once projected)."""
    try:
        return scipy.linalg.cho_solve(scipy.linalg.cho_factor(g), b)
    except (np.linalg.LinAlgError, ValueError):
        return np.linalg.pinv(g, rcond=1e-10, hermitian=True) @ b


class PoseProducts:
    """The fit's whitened residual, its Jacobian's basis and the folds of whole poses, in the
    poses' own terms, so that a shape's columns are scored without being whitened and
    projected row by row: a shape's basis B (M, 6, p) whitens to W = −w B per pose (w the
    pose's 6×6 whitener), and every product the score and the held-out ranking need — WᵀW,
    Wᵀr and qᵀW, q the Jacobian's orthonormal basis — is a sum over poses of B's rows against
    a per-pose matrix made here once (C = wᵀw, d = wᵀr, A = wᵀq). A fold's products are the
    same sums over its poses."""

    def __init__(self, fit: ModelFit, level: float) -> None:
        self.fit = fit
        q = jacobian_basis(fit)
        _, rw, w = fit.refinement.whitened()
        m = len(rw) // 6
        q3, r = q.reshape(m, 6, -1), rw.reshape(m, 6)
        self.q3, self.r = q3, r
        self.c = np.einsum("mik,mil->mkl", w, w)
        self.d = np.einsum("mik,mi->mk", w, r)
        self.a = np.einsum("mik,mir->mkr", w, q3)
        self.level = level
        self.n = len(rw)
        order = np.random.default_rng(0).permutation(m)
        self.folds = [np.sort(order[i::K_FOLDS]) for i in range(K_FOLDS)]
        self.qf = np.stack([np.einsum("mir,mis->rs", q3[f], q3[f]) for f in self.folds])
        self.zf = np.stack([np.einsum("mir,mi->r", q3[f], r[f]) for f in self.folds])

    def stats(self, f: np.ndarray) -> ColumnStats:
        """The projected products of the own-coefficient columns F (M, 6, per): leg k's
        columns are F[:, k] on leg k alone (p = 6·per columns, leg by leg)."""
        per = f.shape[2]
        p = 6 * per
        parts = []
        for idx in self.folds:
            fi = f[idx]
            parts.append(
                (
                    np.einsum("mka,mkl,mlb->kalb", fi, self.c[idx], fi).reshape(p, p),
                    -np.einsum("mkr,mka->rka", self.a[idx], fi).reshape(-1, p),
                    -np.einsum("mka,mk->ka", fi, self.d[idx]).reshape(p),
                )
            )
        return self._projected(parts)

    def in_sample(self, f: np.ndarray) -> ColumnStats:
        """:meth:`stats` of the columns F (M, 6, per) over all poses as one block: the same
        in-sample :meth:`ColumnStats.score` (the folds' products summed: ΣP_fᵀP_f =
        WᵀW − 2XᵀX + Xᵀ(Σ qfᵀqf)X), for a fifth of the work, and no held-out figure — a
        screen over many candidates."""
        per = f.shape[2]
        p = 6 * per
        graw = np.einsum("mka,mkl,mlb->kalb", f, self.c, f).reshape(p, p)
        x = -np.einsum("mkr,mka->rka", self.a, f).reshape(-1, p)
        bw = -np.einsum("mka,mk->ka", f, self.d).reshape(p)
        g = graw - 2.0 * x.T @ x + x.T @ self.qf.sum(0) @ x
        b = bw - x.T @ self.zf.sum(0)
        return ColumnStats(g[None], b[None], graw, self.level)

    def joint_stats(self, basis: np.ndarray) -> ColumnStats:
        """The projected products of a basis (M, 6, p) whose columns span several legs (a
        rigid move's)."""
        parts = []
        for idx in self.folds:
            bi = basis[idx]
            parts.append(
                (
                    np.einsum("mka,mkl,mlb->ab", bi, self.c[idx], bi),
                    -np.einsum("mkr,mka->ra", self.a[idx], bi),
                    -np.einsum("mka,mk->a", bi, self.d[idx]),
                )
            )
        return self._projected(parts)

    def _projected(self, parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> ColumnStats:
        """Each fold's (WᵀW, qᵀW, Wᵀr) projected: P_fᵀP_f and P_fᵀr_f (P = W − q qᵀW)."""
        graws, xs, bws = (list(t) for t in zip(*parts, strict=True))
        x = sum(xs)
        g = np.stack(
            [
                gr - xf.T @ x - x.T @ xf + x.T @ qf @ x
                for gr, xf, qf in zip(graws, xs, self.qf, strict=True)
            ]
        )
        b = np.stack([bw - x.T @ zf for bw, zf in zip(bws, self.zf, strict=True)])
        return ColumnStats(g, b, sum(graws), self.level)


@dataclass
class ColumnStats:
    """A block of columns' products, projected, fold by fold: g (K, p, p) = P_fᵀP_f,
    b (K, p) = P_fᵀr_f; ``raw`` (p, p) the unprojected WᵀW (what the model absorbs of a column
    is judged against it)."""

    g: np.ndarray
    b: np.ndarray
    raw: np.ndarray
    level: float

    def map(self, t: np.ndarray) -> ColumnStats:
        """The products of the columns ``B t`` (t (p, p'): a selection or a sum of columns)."""
        return ColumnStats(t.T @ self.g @ t, self.b @ t, t.T @ self.raw @ t, self.level)

    def _kept(self, g: np.ndarray) -> np.ndarray:
        # A column the model absorbs (its projection a sliver of itself: numerical dust)
        # removes nothing.
        return np.diag(g) > 1e-12 * np.maximum(np.diag(self.raw), 1e-300)

    def score(self) -> float:
        """χ² over the level the columns remove in-sample (the score statistic)."""
        g, b = self.g.sum(0), self.b.sum(0)
        keep = self._kept(g)
        if not keep.any():
            return 0.0
        gk, bk = g[np.ix_(keep, keep)], b[keep]
        return float(bk @ solve(gk, bk)) / self.level

    def heldout(self) -> float:
        """χ² over the level the columns remove from poses they were not fitted to: each
        fold's coefficients fitted on the other folds."""
        return float(self.heldout_folds().sum())

    def heldout_folds(self) -> np.ndarray:
        """(K,) χ² over the level the columns remove from each fold's poses, fitted on the
        other folds (their spread is the held-out figure's standard error)."""
        g, b = self.g.sum(0), self.b.sum(0)
        keep = self._kept(g)
        gains = np.zeros(len(self.g))
        if not keep.any():
            return gains
        ix = np.ix_(keep, keep)
        for i, (gf, bf) in enumerate(zip(self.g, self.b, strict=True)):
            coef = solve((g - gf)[ix], (b - bf)[keep])
            gains[i] = float(2 * coef @ bf[keep] - coef @ gf[ix] @ coef)
        return gains / self.level
