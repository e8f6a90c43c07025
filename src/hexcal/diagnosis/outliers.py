"""Gross outliers: poses inconsistent with every model the catalogue allows.

Real sessions hold a few poses no model explains — a bumped tracker, a pose taken mid-move, a
marker seen through a reflection. Left in, a 0.5 mm outlier is worth a thousand noise-level
residuals: it drags the fit, inflates the excess over the noise floor, and turns the verdict
into ``unexplained``. They are found here before anything is diagnosed:

1. Fit the *richest* model these data allow: the current one plus every available,
   identifiable catalogue effect (what the diagnosis also uses for its estimated noise floor).
   A pose that even this model cannot explain is not missing an effect, it is wrong.
2. Each pose's six leg residuals, whitened by the pose's own 6×6 covariance (the six legs share
   its tracker noise), give a χ² with 6 degrees of freedom when the pose is sound. A pose is an
   outlier when its χ², over the noise level, exceeds the Bonferroni-corrected threshold
   :data:`OUTLIER_ALPHA` / M. The noise level is the stated one — or, when the bulk of the
   poses sits above it (the noise understated, or a structured residual no catalogue effect
   explains), a robust level from the median pose: outliers must stand out from the other
   poses, not only from a stated noise.
3. Refit without the flagged poses and test every pose again — those set aside included, at a
   fit they no longer pull — until the set no longer changes.

Nothing is deleted: the session keeps every pose; the diagnosis says which were set aside, and
is computed on the others (:class:`Subset`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from hexcal.diagnosis.score import Projection
from hexcal.diagnosis.scoring import score_candidate
from hexcal.effects import CATALOGUE, get_effect
from hexcal.effects.drift import T_MID
from hexcal.estimate.effect_fit import ModelFit, Problem, fit_model, fitted_robot
from hexcal.estimate.quantiles import chi2_isf, chi2_ppf
from hexcal.estimate.refine import residual
from hexcal.model.noise import DEFAULT_SIGMAS, leg_whiteners

#: Family-wise false-alarm probability of the outlier test over a whole session (Bonferroni:
#: each of the M poses is tested at OUTLIER_ALPHA / M against χ²(6)). Strict on purpose: a sound
#: pose called an outlier makes a wrong verdict (``outliers``) and hides data, while the gross
#: outliers this is for are tens of noise σ out (0.5 mm against a 10 µm tracker gives a χ² in
#: the thousands) and clear any threshold. For 184 poses the threshold is χ² = 34.5, i.e. a
#: pose about 5.9 σ out; clean simulated sessions reach 25 at most (30 seeds).
OUTLIER_ALPHA = 1e-3
#: At most this share of the poses may be set aside (9 of 184). More poses beyond the threshold
#: are not "a few gross outliers" but a model failing over a region of the workspace or a
#: stretch of time: then none is set aside and the diagnosis says so (see where).
MAX_OUTLIER_FRACTION = 0.05
#: Refits at most. Gross outliers settle in two (find, confirm); a set still changing after
#: this many is a structured residual shifting with the fit, not outliers: none is set aside.
MAX_ITERATIONS = 5


@dataclass(frozen=True)
class Outlier:
    """A pose set aside: its row in the session's table, identity, and how far out it is."""

    index: int  #: 0-based row in the session's measurement table
    pose_id: int
    step: str
    t: float  #: s
    chi2: float  #: its six legs' whitened χ² over the noise level (χ²(6) if it were sound)
    leg: int  #: 1-based, the leg with the largest residual
    residual_mm: float  #: that leg's residual (length the reading says − the pose's), mm

    def text(self) -> str:
        return (
            f"pose {self.pose_id} (step {self.step}, t {self.t:g} s): χ² {self.chi2:.0f} over "
            f"its six legs, leg {self.leg} off by {1000 * self.residual_mm:+.0f} µm"
        )

    def to_dict(self) -> dict:
        return {
            "index": self.index,
            "pose_id": self.pose_id,
            "step": self.step,
            "t": self.t,
            "chi2": self.chi2,
            "leg": self.leg,
            "residual_mm": self.residual_mm,
        }


@dataclass
class Subset(Problem):
    """A session's problem on some of its poses (the rest set aside as outliers).

    The history-dependent bases (backlash: the direction each leg last moved) are the whole
    session's, rows taken; the linear seeds are recomputed without the poses set aside.
    """

    parent: Problem = field(kw_only=True)
    rows: np.ndarray = field(kw_only=True)  #: (n,) row indices into the parent's table

    @classmethod
    def of(cls, parent: Problem, rows: np.ndarray) -> Subset:
        rows = np.asarray(rows, int)
        sub = Problem.build(parent.meas.subset(rows), parent.design, parent.sigmas)
        # Effects reckoned from the session's middle (drift) keep the whole session's.
        t = parent.data.t
        extras = {T_MID: 0.5 * (float(t.min()) + float(t.max())), **parent.data.extras}
        return cls(
            sub.meas,
            sub.design,
            sub.sigmas,
            sub.linear42,
            replace(parent.data.subset(rows), extras=extras),
            parent=parent,
            rows=rows,
        )

    def basis(self, name: str) -> np.ndarray:
        if name not in self._bases:
            self._bases[name] = self.parent.basis(name)[self.rows]
        return self._bases[name]


def session_problem(problem: Problem) -> Problem:
    """The problem over every pose of the session (``problem`` itself unless a :class:`Subset`)."""
    while isinstance(problem, Subset):
        problem = problem.parent
    return problem


@dataclass
class OutlierSearch:
    """Result of :func:`find_outliers`."""

    outliers: list[Outlier]
    problem: Problem  #: the problem on the poses kept (the session's own when none is set aside)
    threshold: float  #: χ² (over the noise level) a pose must exceed
    noise_level: float  #: s²: the pose χ² are divided by it (1 = the stated noise)
    model: tuple[str, ...]  #: the richest model the poses were tested against
    iterations: int
    notes: list[str] = field(default_factory=list)
    #: The fits made on :attr:`problem`'s poses (without cross-validation), for the diagnosis
    #: to reuse: the model searched with, and the richest one; None when the search ended on
    #: other poses than those it last fitted.
    fit: ModelFit | None = None
    rich: ModelFit | None = None

    @property
    def pose_ids(self) -> list[int]:
        return [o.pose_id for o in self.outliers]


def outlier_threshold(m: int, alpha: float = OUTLIER_ALPHA) -> float:
    """χ²(6) quantile a pose must exceed among ``m`` (Bonferroni at family-wise ``alpha``)."""
    return float(chi2_isf(alpha / max(m, 1), 6))


def pose_residuals(problem: Problem, fit: ModelFit) -> np.ndarray:
    """(M, 6) mm over every pose of ``problem`` (also those ``fit`` was not fitted to):
    the length the reading says (reading + offset + effects) − the measured pose's, at the
    fit's parameters, the effects that use the geometry evaluated at the fitted one."""
    ref = fit.refinement
    design = problem.design
    geometric = any(get_effect(e).uses_geometry for e in fit.effects if e != "offset")
    basis, _ = problem.stack(fit.effects, fitted_robot(design, ref) if geometric else None)
    P, R, rho = problem.meas.position, problem.R, problem.meas.readings
    return -residual(ref.x, P, R, rho, design.offsets, "offset" in fit.effects, basis)


def pose_chi2(problem: Problem, fit: ModelFit, residuals: np.ndarray | None = None) -> np.ndarray:
    """(M,) each pose's whitened χ² (its six legs against its 6×6 covariance, the stated noise
    or the typical instruments' without it) at ``fit``, over every pose of ``problem``."""
    res = pose_residuals(problem, fit) if residuals is None else residuals
    ref = fit.refinement
    sig = problem.sigmas if problem.sigmas is not None else DEFAULT_SIGMAS
    W = leg_whiteners(ref.a, ref.b, problem.meas.position, problem.R, sig)
    w = (W @ res[..., None])[..., 0]
    return np.sum(w**2, axis=1)


def _richest(problem: Problem, fit: ModelFit, effects: tuple[str, ...]) -> tuple[str, ...]:
    q = Projection.of(problem, fit)
    extra = []
    for name in CATALOGUE:
        if name in effects:
            continue
        c = score_candidate(problem, fit, name, q)
        if c.available and c.identifiable:
            extra.append(name)
    return (*effects, *extra)


def _noise_level(chi2: np.ndarray, n_params: int, stated: bool) -> float:
    """s² from the median pose (robust to the outliers), its χ² deflated by the fit's leverage
    (the fitted parameters take n_params of the 6n degrees of freedom). Never below the stated
    noise: a pose must stand out from the other poses, and from the instruments' noise."""
    n = len(chi2)
    shrink = max(1.0 - n_params / (6.0 * n), 0.5)
    s2 = float(np.median(chi2) / (chi2_ppf(0.5, 6) * shrink))
    return max(s2, 1.0) if stated else s2


def robust_level(problem: Problem, fit: ModelFit) -> float:
    """s²: the noise level of ``fit``'s residual over ``problem``'s poses from its median pose
    (:func:`_noise_level`): robust to a few poses or a stretch far out, never below the stated
    noise. The outlier search, the change-point search, ``where`` and the covariate explorer
    judge against it, so that a noise understated alike everywhere makes none of them point
    at a particular pose, leg or time."""
    return _noise_level(pose_chi2(problem, fit), fit.n_params, problem.sigmas is not None)


def find_outliers(
    problem: Problem, effects: tuple[str, ...], start: np.ndarray | None = None
) -> OutlierSearch:
    """The poses of ``problem`` (a whole session) that the richest identifiable model of
    ``effects`` + the catalogue cannot explain (see the module docstring). ``start``: row
    indices to set aside at first (an earlier diagnosis' outliers), tested again like any."""
    problem = session_problem(problem)
    m = len(problem.meas)
    threshold = outlier_threshold(m)
    out = np.zeros(m, bool)
    if start is not None and len(start):
        out[np.asarray(start, int)] = True
    sub: Problem = problem
    notes: list[str] = []
    model: tuple[str, ...] = tuple(effects)
    s2 = 1.0
    chi2 = np.zeros(m)
    iterations = 0
    fitted: tuple[Problem, ModelFit, ModelFit] | None = None
    for _ in range(MAX_ITERATIONS):
        iterations += 1
        sub = Subset.of(problem, np.where(~out)[0]) if out.any() else problem
        try:
            fit0 = fit_model(sub, effects, cross_validate=False)
            model = _richest(sub, fit0, tuple(effects))
            rich = fit0
            if len(model) > len(effects):
                rich = fit_model(sub, model, cross_validate=False, seed_fit=fit0)
            fitted = (sub, fit0, rich)
        except (ValueError, np.linalg.LinAlgError) as exc:
            notes.append(f"the search for outliers stopped: the fit without poses failed ({exc})")
            out[:] = False
            sub = problem
            break
        chi2 = pose_chi2(problem, rich)
        s2 = _noise_level(chi2[~out], rich.n_params, problem.sigmas is not None)
        flagged = chi2 / s2 > threshold
        if flagged.sum() > MAX_OUTLIER_FRACTION * m:
            notes.append(
                f"{int(flagged.sum())} of {m} poses lie beyond the outlier threshold (χ² "
                f"{threshold:.1f} over their six legs): too many to be a few gross outliers, "
                "so none is set aside — the model fails over a region or a stretch of time "
                "(see where)"
            )
            out[:] = False
            sub = problem
            break
        if np.array_equal(flagged, out):
            break
        out = flagged
    else:
        notes.append(
            f"the poses beyond the outlier threshold kept changing over {MAX_ITERATIONS} refits: "
            "a structured residual, not a few gross outliers, so none is set aside (see where)"
        )
        out[:] = False
        sub = problem
    outliers = []
    meas = problem.meas
    residuals = pose_residuals(problem, rich) if out.any() else np.zeros((0, 6))
    for i in np.where(out)[0]:
        k = int(np.argmax(np.abs(residuals[i])))
        outliers.append(
            Outlier(
                int(i),
                int(meas.pose_id[i]),
                str(meas.step[i]),
                float(meas.t[i]),
                float(chi2[i] / s2),
                k + 1,
                float(residuals[i, k]),
            )
        )
    search = OutlierSearch(outliers, sub, threshold, s2, model, iterations, notes)
    if fitted is not None and fitted[0] is sub:
        search.fit, search.rich = fitted[1], fitted[2]
    return search
