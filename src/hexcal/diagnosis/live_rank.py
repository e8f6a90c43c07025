"""Live ranking while recording: after each pose, the candidate effects ranked on the poses so
far, from normal equations updated pose by pose — no refit per pose.

Each pose adds six whitened rows: the legs' derivatives by the geometry (a, b and the offsets)
at the current linearisation point, every candidate effect's basis at the pose, and the
residual there. Their products are added to one Gram matrix (a rank-six update). A ranking is
then one solve on the geometry's block: each candidate's Δχ² is the score of its columns once
the geometry's are projected out, and its ΔBIC that less its parameters' cost
(:func:`hexcal.diagnosis.selection.bic_from_chi2`).

The geometry's derivatives depend on where they are taken: every :data:`RELINEARISE` poses the
point moves to the Gauss–Newton solution of the normal equations so far and the matrix is
rebuilt from the poses kept (the one step whose cost grows with the poses, amortised).

An effect's basis at one pose is evaluated on a window of the first pose and the
:data:`WINDOW` poses before this one, with the drift's clock from the first pose (an effect of
the history — backlash's last move, the drift's time — sees what it needs); effects that need
the whole session (a leg's zero steps searched, a tracker's move located) are left out of the
live ranking (:data:`WINDOW_EFFECTS`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from hexcal.diagnosis import selection
from hexcal.effects import CATALOGUE, EffectData, get_effect
from hexcal.effects.drift import T_MID
from hexcal.estimate.layout import ParameterLayout
from hexcal.estimate.leg_rows import pose_jacobian
from hexcal.model.noise import DEFAULT_SIGMAS, NoiseSigmas, leg_whiteners
from hexcal.model.robot import Robot

#: Poses between two moves of the linearisation point (moved earlier, on a leg's clamped sets
#: alone, the step along what they leave open misled the ranking).
RELINEARISE = 100
#: A move of the linearisation point larger than this (mm) is the ridge's, not the data's.
MAX_STEP_MM = 5.0
#: Poses before the new one its effects see (backlash's state is the last move beyond the
#: dead band: a leg still for longer than this is the window's one approximation).
WINDOW = 20
#: The catalogue's effects a window of poses serves (the others need the whole session:
#: a leg's zero steps are searched, a move of the tracker located).
WINDOW_EFFECTS = ("gain", "backlash", "thermal", "compliance", "leadscrew", "drift", "ujoint")


@dataclass
class Rank:
    """One candidate on the poses so far: Δχ² its columns remove (the geometry projected out)
    and ΔBIC (negative: preferred to the model without it)."""

    effect: str
    dchi2: float
    delta_bic: float


@dataclass
class LiveRanking:
    """Candidate effects ranked as poses come (see the module docstring). ``robot``: the
    design (its geometry the first linearisation point); ``sigmas``: the instruments' noise
    (the typical ones when unknown)."""

    robot: Robot
    sigmas: NoiseSigmas | None = None
    fit_offsets: bool = True
    candidates: tuple[str, ...] = WINDOW_EFFECTS
    _poses: list[tuple] = field(default_factory=list)
    _gram: np.ndarray | None = None
    _x: np.ndarray = field(default_factory=lambda: np.zeros(0))
    _widths: list[int] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.lay = ParameterLayout(self.fit_offsets)
        r = self.robot
        x = np.zeros(self.lay.size)
        x[self.lay.a_slice], x[self.lay.b_slice] = r.a.ravel(), r.b.ravel()
        if self.fit_offsets:
            x[self.lay.offsets_slice] = r.offsets
        self._x = x
        self.candidates = tuple(c for c in self.candidates if c in CATALOGUE)
        self._widths = [len(get_effect(c).params(r)) for c in self.candidates]
        self._width = self.lay.n_geometry + sum(self._widths) + 1

    def add(self, position, rotation, readings, t: float, temperature: float | None = None):
        """Record one still pose: P (3,) mm, R (3, 3), readings (6,) mm at t s (and the
        structure's temperature, °C)."""
        pose = (np.asarray(position, float), np.asarray(rotation, float))
        self._poses.append((*pose, np.asarray(readings, float), float(t), temperature))
        n = len(self._poses)
        if n % RELINEARISE == 0:
            self._relinearise()
            return
        rows = self._rows(len(self._poses) - 1)
        self._gram = rows.T @ rows if self._gram is None else self._gram + rows.T @ rows

    def ranking(self) -> list[Rank]:
        """The candidates, best ΔBIC first (after at least a few poses)."""
        if self._gram is None:
            return []
        g = self._gram
        m = self.lay.n_geometry
        n = 6 * len(self._poses)
        # One solve for every candidate's columns and the residual (the last column): the
        # geometry's columns projected out of them all at once.
        proj = g[m:, m:] - g[m:, :m] @ _solve_scaled(g[:m, :m], g[:m, m:])
        out = []
        start = 0
        for name, w in zip(self.candidates, self._widths, strict=True):
            cols = slice(start, start + w)
            start += w
            gr = proj[cols, -1]
            # A candidate the geometry nearly absorbs leaves a block near rank loss: a
            # pseudo-inverse (its columns few, so cheap) rather than a Cholesky solve.
            dchi2 = max(float(gr @ np.linalg.pinv(proj[cols, cols], rcond=1e-10) @ gr), 0.0)
            out.append(Rank(name, dchi2, selection.bic_from_chi2(-dchi2, w, n)))
        return sorted(out, key=lambda r: r.delta_bic)

    def leader(self) -> tuple[Rank | None, float]:
        """(the leading candidate, its margin: the ΔBIC by which it leads the next), or
        (None, nan) when no candidate has very strong evidence yet."""
        ranks = self.ranking()
        if not ranks or not ranks[0].delta_bic < selection.BIC_STRONG:
            return None, float("nan")
        nxt = ranks[1].delta_bic if len(ranks) > 1 else 0.0
        return ranks[0], float(nxt - ranks[0].delta_bic)

    def undo(self) -> None:
        """Take the last pose back out (its rows subtracted: a rank-six downdate)."""
        if not self._poses:
            return
        if self._gram is not None:
            rows = self._rows(len(self._poses) - 1)
            self._gram = self._gram - rows.T @ rows
        self._poses.pop()
        if not self._poses:
            self._gram = None

    def __len__(self) -> int:
        return len(self._poses)

    # -- rows ---------------------------------------------------------------------------------
    def _rows(self, i: int) -> np.ndarray:
        """(6, p + 1) pose i's whitened rows: geometry, candidates' columns, residual."""
        P, R, rho, _, _ = self._poses[i]
        e, jac = pose_jacobian(self._x, self.lay, P[None], R[None], rho[None], self.robot.offsets)
        data = self._window(i)
        cols = [jac[0]] + [
            _basis(c, w, data)[-1] for c, w in zip(self.candidates, self._widths, strict=True)
        ]
        a, b = self.lay.a(self._x), self.lay.b(self._x)
        w = leg_whiteners(a, b, P[None], R[None], self.sigmas or DEFAULT_SIGMAS)[0]
        # The residual's sign as the refinement's: reading − predicted = −e.
        return w @ np.concatenate([*cols, -e[0][:, None]], axis=1)

    def _window(self, i: int) -> EffectData:
        """The effects' inputs on the first pose and the :data:`WINDOW` poses up to pose i."""
        rows = sorted({0, *range(max(i - WINDOW, 0), i + 1)})
        pick = [self._poses[j] for j in rows]
        temps = [p[4] for p in pick]
        return EffectData(
            np.array([p[2] for p in pick]),
            np.array([p[0] for p in pick]),
            np.array([p[1] for p in pick]),
            np.array([p[3] for p in pick]),
            None if any(x is None for x in temps) else np.array(temps, float),
            self.robot,
            self.lay.a(self._x),
            self.lay.b(self._x),
            extras={T_MID: self._poses[0][3]},
        )

    def _relinearise(self, move: bool = True) -> None:
        """Move the linearisation point to the Gauss–Newton step of the normal equations so
        far, and rebuild them there from every pose at once (the effects then see the whole
        recording)."""
        if self._gram is not None and move:
            step = _step(self._gram, self.lay.n_geometry)
            # Before the poses determine the geometry, the step along what they leave open
            # is the ridge's, not the data's: the point stays.
            if np.max(np.abs(step)) <= MAX_STEP_MM:
                self._x = self._x + step
        t = [p[3] for p in self._poses]
        temp = [p[4] for p in self._poses]
        P = np.array([p[0] for p in self._poses])
        R = np.array([p[1] for p in self._poses])
        rho = np.array([p[2] for p in self._poses])
        e, jac = pose_jacobian(self._x, self.lay, P, R, rho, self.robot.offsets)
        a, b = self.lay.a(self._x), self.lay.b(self._x)
        known = not any(x is None for x in temp)
        data = EffectData(
            rho,
            P,
            R,
            np.array(t, float),
            np.array(temp, float) if known else None,
            self.robot,
            a,
            b,
            extras={T_MID: t[0]},
        )
        cols = [jac] + [
            _basis(c, w, data) for c, w in zip(self.candidates, self._widths, strict=True)
        ]
        w = leg_whiteners(a, b, P, R, self.sigmas or DEFAULT_SIGMAS)
        rows = (w @ np.concatenate([*cols, -e[..., None]], axis=-1)).reshape(-1, self._width)
        self._gram = rows.T @ rows


def _basis(name: str, width: int, data: EffectData) -> np.ndarray:
    """(n, 6, width) effect ``name``'s basis, zero where these poses cannot carry it (no
    temperature for thermal, no pitch for leadscrew): it then removes nothing."""
    try:
        return get_effect(name).basis(data)
    except ValueError:
        return np.zeros((len(data), 6, width))


def _step(g: np.ndarray, m: int) -> np.ndarray:
    """The Gauss–Newton step of the geometry (the candidates' columns left out)."""
    return _solve_scaled(g[:m, :m], g[:m, -1])


#: The ridge that keeps a Gram block with unit diagonal solvable before the poses determine
#: every column (the first few poses): far below any determined direction's eigenvalue.
RIDGE = 1e-10


def _solve_scaled(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a⁻¹ b for a Gram block ``a``, its columns scaled to unit norm first, with
    :data:`RIDGE` (a Cholesky solve: an eigendecomposition per pose cost 5 ms)."""
    s = np.sqrt(np.clip(np.diag(a), 1e-300, None))
    scaled = a / np.outer(s, s) + RIDGE * np.eye(len(s))
    bs = b / (s[:, None] if b.ndim == 2 else s)
    x = scipy.linalg.cho_solve(scipy.linalg.cho_factor(scaled), bs)
    return x / (s[:, None] if b.ndim == 2 else s)
