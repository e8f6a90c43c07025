"""Where an unexplained residual points: the residual regressed on a library of covariates.

When no catalogue effect explains the excess over the noise floor, the physical quantity the
residual follows is what points an engineer at the physics. Each covariate is a per-leg
quantity known at every pose (:data:`COVARIATES`): the leg's inclination from the vertical and
the horizontal components of its direction, its position along the stroke (the reading), the
axial force holding the platform's weight, the direction it last moved, the temperature and the
time. Along each, the legs get a shape (:class:`Shape`) — a polynomial of degree 1 to 3
(smooth physics), piecewise linear between knots at the quantiles of the leg's values (local
physics: a dent), or a step where a signed covariate changes sign (play taken up when the load
reverses) — the constant always left to the leg's offset, and only on the legs whose own share
is significant. The score of the shape at the current fit (the model's own parameters projected
out, :func:`hexcal.diagnosis.scoring.block_score`) says how much of the residual it explains.
A covariate counts when its best shape exceeds the Bonferroni-corrected χ² threshold over every
shape tried (:data:`EXPLORE_ALPHA`, scores over the session's noise level), and covariates are
ranked by the score less the shape's parameter cost (ln n per parameter, as BIC). The leading
one is drawn (the residual against it) and written as a ready-to-edit effect file
(:mod:`hexcal.diagnosis.effect_file`).

A leg's inclination is in the library, but on hexapods whose legs swing through a few tens of
degrees the geometry absorbs almost any smooth function of it: a sag ∝ sin²θ is taken up by the
joint positions to 0.1 % (measured on the Left Hand), so it needs no effect and none is named.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from hexcal.diagnosis.scoring import block_score, jacobian_basis, whitened_columns
from hexcal.effects import EffectData
from hexcal.effects.backlash import deadband_mm, motion_state
from hexcal.effects.compliance import leg_forces
from hexcal.estimate.effect_fit import ModelFit, Problem, fitted_robot
from hexcal.estimate.quantiles import chi2_isf

#: Family-wise false-alarm probability over every covariate and shape tried.
EXPLORE_ALPHA = 1e-3
#: Shapes tried along a continuous covariate: polynomials of these degrees (smooth physics: a
#: scale that bends, a stiffness that changes with load) and piecewise-linear shapes with these
#: knot counts (local physics: a dent, a joint that binds past an angle).
DEGREES = (1, 2, 3)
KNOT_COUNTS = (5, 9, 17)
#: A signed covariate (the leg force) is also tried as its sign: play taken up one way or the
#: other when the load reverses. Each sign must hold this share of the poses and legs (a
#: platform carried mostly in compression puts a leg in tension in a few per cent of poses).
MIN_SIGN_SHARE = 0.03


def _unit(data: EffectData) -> np.ndarray:
    v = data.leg_vectors
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _inclination(data: EffectData) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(_unit(data)[..., 2], -1.0, 1.0)))


def _force(data: EffectData) -> np.ndarray:
    mass = data.robot.platform_mass_kg or 1.0
    com = getattr(data.robot, "platform_com_mm", None)
    return leg_forces(data, mass, None if com is None else np.asarray(com, float))


def _per_pose(values: np.ndarray | None) -> np.ndarray:
    return np.repeat(np.asarray(values, float)[:, None], 6, axis=1)


@dataclass(frozen=True)
class Covariate:
    """One quantity the residual may follow: its name (the CLI's and the effect file's), what
    it is (with its unit), what physics it points at, and how it is computed per leg."""

    name: str
    label: str
    unit: str
    points_at: str
    values: Callable[[EffectData], np.ndarray]  #: (M, 6)
    uses_geometry: bool = False
    discrete: bool = False  #: a sign itself: one column per leg, no other shape
    signed: bool = False  #: its sign means something (a load that reverses)


#: The library, in the order the report lists it. The vertical component of a leg's direction
#: is its inclination (cos of it), so only the horizontal components are separate covariates.
COVARIATES: tuple[Covariate, ...] = (
    Covariate(
        "inclination",
        "leg inclination from the vertical",
        "deg",
        "a leg sagging or bending under its own weight, a joint seating with the leg's angle",
        _inclination,
        uses_geometry=True,
    ),
    Covariate(
        "direction_x",
        "x component of the leg's direction",
        "",
        "a joint or an encoder head that reads with the leg's azimuth (joint play, a cable pull)",
        lambda d: _unit(d)[..., 0],
        uses_geometry=True,
    ),
    Covariate(
        "direction_y",
        "y component of the leg's direction",
        "",
        "a joint or an encoder head that reads with the leg's azimuth (joint play, a cable pull)",
        lambda d: _unit(d)[..., 1],
        uses_geometry=True,
    ),
    Covariate(
        "stroke",
        "position along the stroke (the reading)",
        "mm",
        "an encoder scale that bends along the stroke, a dent or a worn stretch of a screw or a "
        "rail",
        lambda d: np.asarray(d.readings, float),
    ),
    Covariate(
        "force",
        "axial leg force holding the platform's weight",
        "N",
        "a leg or a joint that yields non-linearly under load",
        _force,
        uses_geometry=True,
        signed=True,
    ),
    Covariate(
        "last_move",
        "direction of the leg's last move",
        "±1",
        "play or friction that depends on the direction of approach",
        lambda d: motion_state(d.readings, deadband_mm(d)),
        discrete=True,
    ),
    Covariate(
        "temperature",
        "structure temperature",
        "°C",
        "an expansion that is not proportional to the leg length (an encoder, a mount)",
        lambda d: _per_pose(d.temperature),
    ),
    Covariate(
        "time",
        "time since the session started",
        "s",
        "something changing during the session (warm-up, a slipping mount, an encoder drifting)",
        lambda d: _per_pose(np.asarray(d.t, float) - float(np.min(d.t))),
    ),
)


def covariate(name: str) -> Covariate:
    """The library's covariate called ``name``."""
    for c in COVARIATES:
        if c.name == name:
            return c
    raise ValueError(f"no covariate {name!r}; the library: {', '.join(c.name for c in COVARIATES)}")


def knots_of(values: np.ndarray, k: int) -> np.ndarray:
    """(6, k) knots per leg, halfway between the quantiles of each leg's values (M, 6) and even
    spacing over their range: dense where the poses are, but never closer than half the even
    spacing (a clamped leg repeats one reading over a whole step, which would put two quantile
    knots on top of each other)."""
    grid = np.linspace(0.0, 1.0, k)
    lo, hi = values.min(axis=0), values.max(axis=0)
    even = lo[:, None] + grid[None, :] * (hi - lo)[:, None]
    return 0.5 * (np.quantile(values, grid, axis=0).T + even)


def hats(u: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """(M, k − 1) piecewise-linear hat functions at ``knots`` (k,) evaluated at ``u`` (M,),
    the first left out (its constant is the leg's offset); flat beyond the end knots."""
    u = np.clip(u, knots[0], knots[-1])
    eye = np.eye(len(knots))
    return np.column_stack([np.interp(u, knots, eye[j]) for j in range(1, len(knots))])


@dataclass(frozen=True)
class Shape:
    """A family of per-leg shapes along a covariate: ``kind`` ``"poly"`` (powers 1 … ``degree``
    of the covariate about each leg's ``centre`` over its ``half`` range), ``"knots"``
    (piecewise linear between ``knots`` (6, k)) or ``"sign"`` (the covariate's sign, or the
    covariate itself when it is a sign); ``legs`` (1-based) those that carry it."""

    kind: str
    degree: int = 0
    knots: np.ndarray | None = None
    centre: np.ndarray | None = None  #: (6,)
    half: np.ndarray | None = None  #: (6,)
    legs: tuple[int, ...] = (1, 2, 3, 4, 5, 6)

    @property
    def per_leg(self) -> int:
        if self.kind == "poly":
            return self.degree
        if self.kind == "knots" and self.knots is not None:
            return self.knots.shape[1] - 1
        return 1

    def columns(self, u: np.ndarray, k: int) -> np.ndarray:
        """(M, per_leg) leg ``k``'s (0-based) shape columns at its covariate values ``u``."""
        if self.kind == "poly" and self.centre is not None and self.half is not None:
            x = (u - self.centre[k]) / self.half[k]
            return np.column_stack([x**j for j in range(1, self.degree + 1)])
        if self.kind == "knots" and self.knots is not None:
            return hats(u, self.knots[k])
        return np.sign(u)[:, None]

    def basis(self, values: np.ndarray) -> np.ndarray:
        """(M, 6, len(legs) · per_leg) mm per mm: each carrying leg's shape in its columns."""
        per = self.per_leg
        out = np.zeros((len(values), 6, len(self.legs) * per))
        for i, leg in enumerate(self.legs):
            out[:, leg - 1, i * per : (i + 1) * per] = self.columns(values[:, leg - 1], leg - 1)
        return out

    def with_legs(self, legs: tuple[int, ...]) -> Shape:
        return Shape(self.kind, self.degree, self.knots, self.centre, self.half, legs)

    def describe(self) -> str:
        if self.kind == "poly":
            return {1: "a straight line", 2: "a parabola", 3: "a cubic"}[self.degree]
        if self.kind == "knots" and self.knots is not None:
            return f"piecewise linear, {self.knots.shape[1]} knots"
        return "a step at its sign change"

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "degree": self.degree or None,
            "knots": None if self.knots is None else self.knots.tolist(),
            "centre": None if self.centre is None else self.centre.tolist(),
            "half": None if self.half is None else self.half.tolist(),
            "legs": list(self.legs),
        }


def shapes_for(cov: Covariate, values: np.ndarray) -> list[Shape]:
    """The shapes tried along ``cov`` at its ``values`` (M, 6)."""
    if cov.discrete:
        return [Shape("sign")]
    lo, hi = values.min(axis=0), values.max(axis=0)
    centre, half = 0.5 * (lo + hi), np.maximum(0.5 * (hi - lo), 1e-12)
    out = [Shape("poly", degree=d, centre=centre, half=half) for d in DEGREES]
    out += [Shape("knots", knots=knots_of(values, k)) for k in KNOT_COUNTS]
    if cov.signed and min((values > 0).mean(), (values < 0).mean()) >= MIN_SIGN_SHARE:
        out.append(Shape("sign"))
    return out


@dataclass
class Lead:
    """One covariate's best shape at the fit."""

    covariate: Covariate
    values: np.ndarray  #: (M, 6) the covariate at each pose and leg
    shape: Shape
    score: float  #: χ² the shape removes (first order), over the noise level
    threshold: float  #: the score it must exceed to count
    share: float  #: of the excess χ² over the floor it explains alone
    merit: float  #: score − columns · ln n: what ranks the covariates
    significant: bool = False

    @property
    def columns(self) -> int:
        return len(self.shape.legs) * self.shape.per_leg

    @property
    def points_at(self) -> str:
        """The physics the covariate, in this shape, points at."""
        if self.shape.kind == "sign" and self.covariate.signed:
            return "play in a leg's joints, taken up one way or the other as its load reverses"
        return self.covariate.points_at

    def text(self) -> str:
        c = self.covariate
        legs = self.shape.legs
        on = (
            "every leg"
            if len(legs) == 6
            else "leg" + "s" * (len(legs) > 1) + " " + ", ".join(map(str, legs))
        )
        return (
            f"{c.label} ({c.name}; {self.shape.describe()} on {on}): explains "
            f"{100 * self.share:.0f} % of the excess (χ² {self.score:.0f} with {self.columns} "
            f"shape parameters, threshold {self.threshold:.0f})"
        )

    def to_dict(self) -> dict:
        c = self.covariate
        return {
            "covariate": c.name,
            "label": c.label,
            "unit": c.unit,
            "points_at": self.points_at,
            "share_of_excess": self.share,
            "chi2": self.score,
            "columns": self.columns,
            "threshold": self.threshold,
            "shape": self.shape.to_dict(),
            "significant": self.significant,
        }


@dataclass
class Exploration:
    """What the residual follows: every covariate's best shape, the significant ones first,
    best first."""

    tested: list[Lead] = field(default_factory=list)
    level: float = 1.0

    @property
    def leads(self) -> list[Lead]:
        return [t for t in self.tested if t.significant]

    @property
    def lead(self) -> Lead | None:
        return self.leads[0] if self.leads else None

    def summary(self) -> str:
        if not self.leads:
            return (
                "the residual follows none of the covariates ("
                + ", ".join(c.name for c in COVARIATES)
                + ")"
            )
        return "the residual follows " + "; ".join(t.text() for t in self.leads[:3])

    def to_dict(self) -> dict:
        return {
            "summary": self.summary(),
            "leads": [t.to_dict() for t in self.leads],
            "tested": [t.to_dict() for t in self.tested],
            "noise_level": self.level,
        }


def covariate_values(problem: Problem, fit: ModelFit, cov: Covariate) -> np.ndarray | None:
    """(M, 6) ``cov`` at ``problem``'s poses (at the fitted geometry when it uses it), or None
    when the data cannot carry it (no temperature, or one that hardly changed)."""
    data = problem.data
    if cov.uses_geometry:
        data = data.at_geometry(fitted_robot(problem.design, fit.refinement))
    if cov.name == "temperature" and (data.temperature is None or np.ptp(data.temperature) < 0.2):
        return None
    values = np.asarray(cov.values(data), float)
    if not np.all(np.isfinite(values)) or np.all(np.ptp(values, axis=0) == 0):
        return None
    return values


def explore(problem: Problem, fit: ModelFit, s2: float, level: float) -> Exploration:
    """Every covariate's best shape at ``fit`` (see the module docstring): ``s2`` the noise
    level of the floor (for the share of the excess), ``level`` the session's own noise level
    the scores are judged against (at least ``s2``)."""
    q = jacobian_basis(fit)
    n = fit.refinement.whitened()[1].size
    excess = fit.chi2 - fit.dof * s2
    tried = []
    for cov in COVARIATES:
        values = covariate_values(problem, fit, cov)
        if values is not None:
            tried += [(cov, values, shape) for shape in shapes_for(cov, values)]
    tests = max(len(tried), 1)
    best: dict[str, Lead] = {}
    for cov, values, shape in tried:
        lead = _carried(fit, q, cov, values, shape, tests, level)
        score = lead.score * level
        lead.share = float(score / excess) if excess > 0 else float("nan")
        lead.merit = lead.score - lead.columns * np.log(n)
        held = best.get(cov.name)
        if held is None or (lead.significant, lead.merit) > (held.significant, held.merit):
            best[cov.name] = lead
    tested = sorted(best.values(), key=lambda t: (not t.significant, -t.merit))
    return Exploration(tested, level)


def _carried(
    fit: ModelFit,
    q: np.ndarray,
    cov: Covariate,
    values: np.ndarray,
    shape: Shape,
    tests: int,
    level: float,
) -> Lead:
    """``shape`` on the legs whose own score exceeds the per-leg threshold (all six when none
    does), and its score over ``level``: a dent or a binding joint is one leg's, and a shape
    on six legs would spend five legs' parameters on noise."""
    per = shape.per_leg
    cols = whitened_columns(fit, shape.basis(values))
    leg_threshold = float(chi2_isf(EXPLORE_ALPHA / (6 * tests), per))
    legs = tuple(
        leg
        for i, leg in enumerate(shape.legs)
        if block_score(fit, cols[:, i * per : (i + 1) * per], q) / level > leg_threshold
    )
    if legs and len(legs) < 6:
        shape = shape.with_legs(legs)
        cols = whitened_columns(fit, shape.basis(values))
    p = cols.shape[1]
    score = block_score(fit, cols, q) / level
    threshold = float(chi2_isf(EXPLORE_ALPHA / tests, p))
    significant = bool(legs) and bool(score > threshold)
    return Lead(cov, values, shape, float(score), threshold, 0.0, 0.0, significant)
