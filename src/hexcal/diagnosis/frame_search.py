"""Where the tracker (or the robot's base) moved during the session: a search for every leg
changing together at one pose in the pattern of a rigid move, told apart from a smooth drift.

A tracker knocked mid-session measures every later pose in a moved frame: each leg's length
computed from the tracked pose is off by n_k·(v + ω × p_k) from that pose on
(:func:`hexcal.effects.frame_step.rigid_move_basis`). For every split of the poses in recording
order, the score of that six-column block from the split on (the model's own parameters
projected out) says how much χ² the move would remove; the best split is a frame step when its
score exceeds the Bonferroni-corrected χ²(6) threshold over the splits (:data:`FRAME_ALPHA`).
One leg's step alone is not a move: the move's five more parameters must explain what the best
single leg's step at the same split does not. What the move removes beyond the same move
drifting smoothly in time (:func:`_move_beyond_smooth`) must pass the same threshold, or the
move is a curve, not a step (a stand settling, uneven warm-up); whether the step,
a steady drift (the catalogue's ``drift``) or one leg's zero step tells the story is then
the verdict's (each is scored, refitted and compared as an effect): a knocked tracker moves
six legs with six parameters, where six zero steps need twelve.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from hexcal.diagnosis.outliers import Subset
from hexcal.diagnosis.pose_products import PoseProducts
from hexcal.effects.frame_step import rigid_move_basis
from hexcal.estimate.effect_fit import ModelFit, Problem, fitted_robot
from hexcal.estimate.quantiles import chi2_isf
from hexcal.model.robot import FrameStep

#: Family-wise false-alarm probability of the search over a session.
FRAME_ALPHA = 1e-3
#: Poses on each side of a split at least.
MIN_SIDE = 3
#: The time constants (shares of the session's span) of the warm-up curves a step must beat.
SMOOTH_TAUS = (0.1, 0.3)


@dataclass(frozen=True)
class FrameChange:
    """A located rigid move of the measuring frame."""

    index: int  #: row of the first pose after the move
    pose_id: int
    t_s: float  #: s, halfway between the last pose before and the first after
    move_um: tuple[float, float, float]  #: the translation, µm (first order)
    turn_urad: tuple[float, float, float]  #: the rotation, µrad
    chi2: float  #: Δχ² the move removes, over the noise level
    threshold: float
    smooth_chi2: float  #: what the move removes beyond the same move drifting smoothly

    def text(self) -> str:
        v = float(np.linalg.norm(self.move_um))
        w = float(np.degrees(np.linalg.norm(self.turn_urad) * 1e-6))
        return (
            f"the tracker (or the robot's base) moved at pose {self.pose_id} (t {self.t_s:g} s): "
            f"every leg changed together as a rigid move of {v:.0f} µm and {w:.4f}° would make "
            f"them (a move there removes χ² {self.chi2:.0f}, {self.smooth_chi2:.0f} beyond a smooth "
            f"drift; threshold {self.threshold:.0f}): was the tracker or its stand knocked?"
        )

    def to_dict(self) -> dict:
        return {
            "index": self.index,
            "pose_id": self.pose_id,
            "t_s": self.t_s,
            "move_um": list(self.move_um),
            "turn_urad": list(self.turn_urad),
            "chi2": self.chi2,
            "threshold": self.threshold,
            "smooth_chi2": self.smooth_chi2,
            "text": self.text(),
        }


def _suffix(a: np.ndarray) -> np.ndarray:
    return np.cumsum(a[::-1], axis=0)[::-1]


def _time_spline(problem: Problem) -> np.ndarray:
    """(M, 4) smooth curves of the session's time T: t/T, (t/T)² and 1 − e^(−t/τ) at τ of
    :data:`SMOOTH_TAUS` (warm-up saturating early or late); none can bend sharply in the
    middle of a session, as a step does."""
    t = np.asarray(problem.meas.t, float)
    u = (t - t.min()) / max(float(np.ptp(t)), 1e-12)
    return np.column_stack([u, u**2, *(1.0 - np.exp(-u / tau) for tau in SMOOTH_TAUS)])


def leg_step_beyond_smooth(pp: PoseProducts, problem: Problem, leg: int, index: int) -> float:
    """χ² over the level that leg ``leg``'s step from row ``index`` on removes beyond a smooth
    curve of that leg's residual in time (uneven heating is a curve: a step then adds
    nothing to it, where a lost count does)."""
    cols = _time_spline(problem)
    m = len(cols)
    after = (np.arange(m) >= index).astype(float)[:, None]
    f = np.zeros((m, 6, cols.shape[1] + 1))
    f[:, leg - 1] = np.column_stack([cols, after])
    per = f.shape[2]
    st = pp.stats(f).map(np.eye(6 * per)[:, (leg - 1) * per : leg * per])
    smooth = st.map(np.eye(per)[:, : per - 1])
    return st.score() - smooth.score()


def _move_beyond_smooth(pp: PoseProducts, problem: Problem, j6: np.ndarray, index: int) -> float:
    """χ² over the level that the rigid move from row ``index`` on removes beyond the same
    move drifting smoothly in time (each of its six components a smooth curve): a tracker
    warming up, a stand settling, is a curve; a knock is a step the curve cannot follow."""
    cols = _time_spline(problem)
    m = len(cols)
    drift = (j6[:, :, :, None] * cols[:, None, None, :]).reshape(m, 6, -1)
    step = j6 * (np.arange(m) >= index)[:, None, None]
    st = pp.joint_stats(np.concatenate([drift, step], axis=-1))
    p = drift.shape[-1]
    return st.score() - st.map(np.eye(p + 6)[:, :p]).score()


def _one_leg_scores(pp: PoseProducts, splits: np.ndarray, z: np.ndarray) -> np.ndarray:
    """(S, 6) the χ² a step of one leg alone from each split on removes (not over the level):
    the column of leg k is its whitened reading from the split on."""
    g = _suffix(np.einsum("mkk->mk", pp.c))[splits]
    b = _suffix(-pp.d)[splits]
    x = _suffix(-pp.a)[splits]  # (S, 6, r)
    gp = g - np.einsum("skr,skr->sk", x, x)
    bp = b - x @ z
    ok = gp > 1e-12 * np.maximum(g, 1e-300)
    return np.where(ok, bp**2 / np.where(ok, gp, 1.0), 0.0)


def search_frame(
    problem: Problem, fit: ModelFit, level: float, products: PoseProducts | None = None
) -> FrameChange | None:
    """The best rigid move of the frame at ``fit`` (see the module docstring), or None when
    none beats the threshold and a smooth drift, or the poses are not in recording order."""
    meas = problem.meas
    m = len(meas)
    t = np.asarray(meas.t, float)
    if m < 2 * MIN_SIDE + 1 or not np.all(np.diff(t) > 0):
        return None
    pp = products if products is not None else PoseProducts(fit, level)
    data = problem.data.at_geometry(fitted_robot(problem.design, fit.refinement))
    j6 = rigid_move_basis(data)  # (M, 6 legs, 6)
    splits = np.arange(MIN_SIDE, m - MIN_SIDE + 1)
    g = _suffix(np.einsum("mka,mkl,mlb->mab", j6, pp.c, j6))[splits]
    bw = _suffix(-np.einsum("mka,mk->ma", j6, pp.d))[splits]
    x = _suffix(-np.einsum("mkr,mka->mra", pp.a, j6))[splits]  # (S, r, 6)
    z = np.einsum("mir,mi->r", pp.q3, pp.r)
    gp = g - np.einsum("sra,srb->sab", x, x)
    bp = bw - np.einsum("sra,r->sa", x, z)
    coef = np.linalg.pinv(gp, rcond=1e-10, hermitian=True) @ bp[..., None]
    scores = np.einsum("sa,sa->s", bp, coef[..., 0]) / level
    # Every leg together, not one alone: the move's five more parameters must explain what
    # the best single leg's step at the same split does not.
    beyond = scores - _one_leg_scores(pp, splits, z).max(axis=1) / level
    j = int(np.argmax(beyond))
    threshold = float(chi2_isf(FRAME_ALPHA / len(splits), 6))
    if not (scores[j] > threshold and beyond[j] > chi2_isf(FRAME_ALPHA / len(splits), 5)):
        return None
    i = int(splits[j])
    smooth = _move_beyond_smooth(pp, problem, j6, i)
    # A step is named only where it beats a smooth curve of the same series: a stand settling
    # or a tracker warming up (a drift already in the model leaving its curvature) is a curve.
    if not smooth > threshold:
        return None
    c = -coef[j, :, 0]
    return FrameChange(
        i,
        int(meas.pose_id[i]),
        float(0.5 * (t[i - 1] + t[i])),
        (float(c[0]), float(c[1]), float(c[2])),
        (float(c[3]), float(c[4]), float(c[5])),
        float(scores[j]),
        threshold,
        float(smooth),
    )


def locate_frame(problem: Problem, change: FrameChange | None) -> None:
    """Give ``problem`` (and the session it is part of) the design with ``change`` as its
    ``frame_steps``, so that the ``frame_step`` effect is evaluated there; None leaves the
    design's own as they are."""
    if change is None:
        return
    steps = [FrameStep(t_s=change.t_s)]
    p: Problem | None = problem
    while p is not None:
        design = p.design.model_copy(update={"frame_steps": steps})
        p.design = design
        p.data = replace(p.data, robot=design)
        p._bases.pop("frame_step", None)
        p._missing.pop("frame_step", None)
        p = p.parent if isinstance(p, Subset) else None
