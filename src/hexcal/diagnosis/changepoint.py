"""Where one leg's zero changed during the session: a change-point search on each leg's
residual in recording order.

A leg that loses counts, or is re-homed, mid-session reads a constant amount longer or shorter
from that pose on. The fit spreads the step over the leg's offset, so the residual shows it as
a mean shift between two stretches of the session. For every leg and every split of the poses
in recording order, the score statistic of a step there (the model's own parameters projected
out, as :func:`hexcal.diagnosis.scoring.projected_scores` does, here through the normal
equations and sums over the poses after the split) says how much χ² the step would remove;
the best split of a leg is a change point when its score, over the session's noise level,
exceeds the Bonferroni-corrected χ²(1) threshold over all the splits tried
(:data:`STEP_ALPHA`). Located steps become the ``zero_step`` effect's times
(:func:`locate`), so that the effect is scored, refitted and named like any other.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from hexcal.diagnosis.outliers import Subset
from hexcal.diagnosis.score import span_pinv
from hexcal.effects.zero_step import steps_of
from hexcal.estimate.effect_fit import ModelFit, Problem
from hexcal.estimate.quantiles import chi2_isf
from hexcal.model.robot import ZeroStep

#: Family-wise false-alarm probability of the search over a session (Bonferroni over the six
#: legs and every split): a sound session shows a change point once in a thousand.
STEP_ALPHA = 1e-3
#: Poses on each side of a split at least.
MIN_SIDE = 3


@dataclass(frozen=True)
class ChangePoint:
    """A located change of one leg's zero."""

    leg: int  #: 1-based
    index: int  #: row of the first pose after the change
    pose_id: int  #: that pose's id
    t_s: float  #: s, halfway between the last pose before and the first after
    size_mm: float  #: δ: how much longer the leg reads after the change (first order)
    chi2: float  #: Δχ² the step removes, over the noise level
    threshold: float  #: what it had to exceed

    def text(self) -> str:
        how = "long" if self.size_mm > 0 else "short"
        return (
            f"leg {self.leg} reads {abs(1000 * self.size_mm):.0f} µm {how} from pose "
            f"{self.pose_id} on (t {self.t_s:g} s; a step there removes χ² {self.chi2:.0f}, "
            f"threshold {self.threshold:.0f}): lost counts, or a re-home?"
        )

    def to_dict(self) -> dict:
        return {
            "leg": self.leg,
            "index": self.index,
            "pose_id": self.pose_id,
            "t_s": self.t_s,
            "size_mm": self.size_mm,
            "chi2": self.chi2,
            "threshold": self.threshold,
            "text": self.text(),
        }


def search(problem: Problem, fit: ModelFit, level: float = 1.0) -> list[ChangePoint]:
    """The change points of ``problem``'s poses at ``fit`` (see the module docstring); scores
    are divided by the noise ``level`` (s², at least 1 with the stated noise). Legs are taken
    greedily: the strongest step first, then each further leg's best step scored with the
    steps already found projected out (one real step leaks into the other legs' residual
    through the shared geometry). Empty when the poses' times do not increase in table order
    (no recording order to search)."""
    meas = problem.meas
    m = len(meas)
    t = np.asarray(meas.t, float)
    if m < 2 * MIN_SIDE + 1 or not np.all(np.diff(t) > 0):
        return []
    splits = np.arange(MIN_SIDE, m - MIN_SIDE + 1)
    threshold = float(chi2_isf(STEP_ALPHA / (6 * len(splits)), 1))
    jw, rw, w = fit.refinement.whitened()
    # The step column of leg k at split s is g_k at every pose from s on, g_k (M, 6) the
    # whitened reading of leg k (column k of each pose's whitener; whitened_columns' sign).
    # Every product the score needs is then a sum over poses m ≥ s of a per-pose term — one
    # suffix sum per leg, where the columns themselves would be (6M, M) — and the model's
    # columns A (the whitened Jacobian, then the steps found) are projected out through their
    # normal equations: ‖c⊥‖² = cᵀc − cᵀA (AᵀA)⁺ Aᵀc, c⊥ᵀr = cᵀr − cᵀA (AᵀA)⁺ Aᵀr. Nothing
    # larger than the Jacobian itself is made (a QR of it held three copies).
    rw3 = rw.reshape(m, 6)
    gs = [np.ascontiguousarray(w[:, :, k]) for k in range(6)]
    own = [_suffix(np.einsum("mi,mi->m", g, rw3))[splits] for g in gs]  # cᵀr (S,)
    sq = [_suffix(np.einsum("mi,mi->m", g, g))[splits] for g in gs]  # cᵀc (S,)
    jw3 = jw.reshape(m, 6, -1)
    cross = [_suffix(np.einsum("mip,mi->mp", jw3, g))[splits] for g in gs]  # cᵀJ (S, p)
    gram = jw.T @ jw
    atr = jw.T @ rw
    steps = np.zeros((len(rw), 0))  # the steps found, whole: (6M, f)
    found: list[ChangePoint] = []
    while len(found) < 6:
        inv = span_pinv(gram)
        coef_r = inv @ atr
        best = None
        for k in set(range(6)) - {c.leg - 1 for c in found}:
            x = cross[k]  # (S, p + f) cᵀA
            norm2 = sq[k] - np.einsum("sp,sp->s", x @ inv, x)
            dot = own[k] - x @ coef_r
            ok = norm2 > 1e-8 * np.maximum(sq[k], 1e-300)
            scores = np.where(ok, dot**2 / np.where(ok, norm2, 1.0), 0.0) / level
            j = int(np.argmax(scores))
            if scores[j] > threshold and (best is None or scores[j] > best[0]):
                best = (float(scores[j]), k, j, float(dot[j] / norm2[j]))
        if best is None:
            break
        score, k, j, coef = best
        i = int(splits[j])
        # The whitened residual is the model's prediction less the reading: a positive
        # coefficient of the column −[after] is a leg reading short.
        found.append(
            ChangePoint(
                k + 1,
                i,
                int(meas.pose_id[i]),
                float(0.5 * (t[i - 1] + t[i])),
                -coef,
                score,
                threshold,
            )
        )
        # Condition the other legs on this step: it joins the model's columns.
        s3 = np.zeros((m, 6))
        s3[i:] = gs[k][i:]
        step = s3.reshape(-1)
        a_s = np.concatenate([jw.T @ step, steps.T @ step])
        gram = np.block([[gram, a_s[:, None]], [a_s[None, :], np.array([[step @ step]])]])
        atr = np.append(atr, step @ rw)
        steps = np.column_stack([steps, step])
        cross = [
            np.column_stack([x, _suffix(np.einsum("mi,mi->m", s3, g))[splits]])
            for x, g in zip(cross, gs, strict=True)
        ]
    return found


def _suffix(a: np.ndarray) -> np.ndarray:
    """Sums over the poses from each row on: row s of the result is ``a[s:].sum(0)``."""
    return np.cumsum(a[::-1], axis=0)[::-1]


def locate(problem: Problem, changes: list[ChangePoint]) -> None:
    """Give ``problem`` (and the session it is part of) the design with ``changes`` as its
    ``zero_steps``, so that the ``zero_step`` effect is evaluated at them; an empty list
    leaves the design's own (stated in robot.json) as they are."""
    if not changes:
        return
    steps = [ZeroStep(leg=c.leg, t_s=c.t_s) for c in changes]
    p: Problem | None = problem
    while p is not None:
        design = p.design.model_copy(update={"zero_steps": steps})
        p.design = design
        p.data = replace(p.data, robot=design)
        p._bases.pop("zero_step", None)
        p._missing.pop("zero_step", None)  # asked before the steps were located
        p = p.parent if isinstance(p, Subset) else None


def located(problem: Problem) -> bool:
    """Whether the problem's design holds zero steps (located or stated)."""
    return bool(steps_of(problem.design))
