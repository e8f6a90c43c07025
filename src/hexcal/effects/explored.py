"""An effect found by exploring the residual: a shape along a covariate.

The diagnosis' explorer (:mod:`hexcal.diagnosis.explorer`) tries shapes (:class:`Shape`) along
every covariate (:mod:`hexcal.effects.covariates`) and writes the best as an effect file whose
effect is an :class:`ExploredEffect`: the same covariate, the same shape with the same knots,
period or split, so that the file loaded unedited fits exactly what the explorer scored.

Shapes, each the constant left out (the leg's offset holds it):

- ``line``: the covariate about the middle of its range, over half its range;
- ``spline``: a cubic B-spline with interior knots at the covariate's quantiles (a smooth
  curve; the explorer chooses how many by cross-validation);
- ``periodic``: a sine and a cosine of the covariate at one period (the period a
  periodogram over the covariate finds), and at ``harmonics`` − 1 of its harmonics (an
  encoder's interpolation error, a screw's wobble: cycles that are not pure sines);
- ``step``: 0 below a split value of the covariate, 1 from it on (a change point);
- ``sign``: the covariate's sign (play taken up one way or the other as a load reverses, the
  direction of the last move);
- ``hinge``: a straight line and the same covariate beyond a split value (two lines meeting
  there: a dead band, a stop, a V about a level);
- ``product``: along a product covariate ``A*B`` (:mod:`hexcal.effects.interactions`), the
  bilinear surface ``a·b``, ``a``, ``b`` — ``a`` and ``b`` the two covariates about the middles
  of their ranges, over half their ranges (the lines ``a`` and ``b``: an interaction with its
  main effects).

Each in a scope: on the legs ``legs``, each with its own coefficients, or (``shared``) one set
of coefficients for all of them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import BSpline

from hexcal.effects.base import Effect, EffectData, ParamSpec
from hexcal.effects.covariates import covariate_factors, covariate_values
from hexcal.effects.interactions import parse_product
from hexcal.effects.lagged import series_of

#: Each coefficient's plausible range and the resolution identifiability asks of it, µm.
PLAUSIBLE_UM = (-1000.0, 1000.0)
RESOLUTION_UM = 20.0
KINDS = ("line", "spline", "periodic", "step", "sign", "hinge", "product")
#: A periodic shape's harmonics at most (the explorer tries 1 to this many).
MAX_HARMONICS = 3


def _row(values) -> np.ndarray:
    return np.asarray(values, float).reshape(6, -1)


@dataclass(frozen=True)
class Shape:
    """A shape along a covariate, per leg (arrays are per leg, legs 1-6 in rows).

    ``centre``, ``half`` (6,): the line's middle and half-range; ``lo``, ``hi`` (6,) and
    ``knots`` (6, n): the spline's boundary and interior knots; ``period``: the periodic
    shape's, in the covariate's unit, and ``harmonics`` how many it holds (1: the period's
    sine alone; 2: with the half period's too …); ``split`` (6,): the step's value; ``centre2``,
    ``half2`` (6,): a product's second covariate's middle and half-range (its first's are
    ``centre`` and ``half``)."""

    kind: str
    legs: tuple[int, ...] = (1, 2, 3, 4, 5, 6)
    shared: bool = False
    centre: tuple[float, ...] = ()
    half: tuple[float, ...] = ()
    lo: tuple[float, ...] = ()
    hi: tuple[float, ...] = ()
    knots: tuple[tuple[float, ...], ...] = ()
    period: float = 0.0
    split: tuple[float, ...] = ()
    centre2: tuple[float, ...] = ()
    half2: tuple[float, ...] = ()
    harmonics: int = 1
    extra: dict = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"shape kind {self.kind!r}: one of {', '.join(KINDS)}")
        if not self.legs or not set(self.legs) <= set(range(1, 7)):
            raise ValueError(f"shape legs {self.legs}: 1 to 6, at least one")
        if self.kind == "periodic" and not self.period > 0:
            raise ValueError(f"a periodic shape needs a period > 0 (got {self.period})")
        if not (isinstance(self.harmonics, int) and 1 <= self.harmonics <= MAX_HARMONICS):
            raise ValueError(f"harmonics {self.harmonics!r}: an integer from 1 to {MAX_HARMONICS}")

    @property
    def per_leg(self) -> int:
        """Columns per leg (the shared scope has this many in all)."""
        if self.kind == "spline":
            return len(self.knots[0]) + 3
        if self.kind == "product":
            return 3
        if self.kind == "periodic":
            return 2 * self.harmonics
        return 2 if self.kind == "hinge" else 1

    @property
    def n_params(self) -> int:
        return self.per_leg * (1 if self.shared else len(self.legs))

    def columns(self, u: np.ndarray, k: int) -> np.ndarray:
        """(M, per_leg) leg ``k``'s (0-based) columns at its covariate values ``u`` (M,),
        a product's at its two covariates' (M, 2)."""
        u = np.asarray(u, float)
        if self.kind == "product":
            a = (u[:, 0] - self.centre[k]) / self.half[k]
            b = (u[:, 1] - self.centre2[k]) / self.half2[k]
            return np.column_stack([a * b, a, b])
        if self.kind == "line":
            return ((u - self.centre[k]) / self.half[k])[:, None]
        if self.kind == "spline":
            lo, hi = self.lo[k], self.hi[k]
            t = np.r_[[lo] * 4, self.knots[k], [hi] * 4]
            x = np.clip(u, lo, hi)
            return BSpline.design_matrix(x, t, 3).toarray()[:, 1:]
        if self.kind == "periodic":
            w = 2.0 * np.pi * u / self.period
            return np.column_stack(
                [f(h * w) for h in range(1, self.harmonics + 1) for f in (np.sin, np.cos)]
            )
        if self.kind == "step":
            return (u >= self.split[k]).astype(float)[:, None]
        if self.kind == "hinge":
            return (
                np.column_stack([u - self.centre[k], np.maximum(u - self.split[k], 0.0)])
                / (self.half[k])
            )
        return np.sign(u)[:, None]

    def basis(self, values: np.ndarray) -> np.ndarray:
        """(M, 6, n_params) mm per mm: the shape at the covariate ``values`` (M, 6); a
        product's at its two covariates' (M, 6, 2)."""
        per = self.per_leg
        out = np.zeros((len(values), 6, self.n_params))
        for i, leg in enumerate(self.legs):
            cols = slice(0, per) if self.shared else slice(i * per, (i + 1) * per)
            out[:, leg - 1, cols] = self.columns(values[:, leg - 1], leg - 1)
        return out

    def with_legs(self, legs: tuple[int, ...], shared: bool | None = None) -> Shape:
        from dataclasses import replace

        return replace(self, legs=tuple(legs), shared=self.shared if shared is None else shared)

    def describe(self, unit: str = "") -> str:
        """The shape in words (``unit``: the covariate's, for the period)."""
        per = f" {unit}" if unit else ""
        what = {
            "line": "a straight line",
            "spline": (
                f"a smooth curve ({len(self.knots[0])} interior knots)"
                if self.knots and len(self.knots[0])
                else "a cubic curve"
            ),
            "periodic": f"a periodic error of period {self.period:.4g}{per}"
            + (
                f" with {self.harmonics - 1} harmonic{'s' * (self.harmonics > 2)}"
                if self.harmonics > 1
                else ""
            ),
            "step": "a step (a change point)",
            "hinge": "a bend (two straight lines meeting at one value)",
            "sign": "a step at its sign change",
            "product": "a bilinear surface (the product and its two lines)",
        }[self.kind]
        return what + (", one coefficient shared by the legs" if self.shared else "")

    def to_dict(self) -> dict:
        d: dict = {"kind": self.kind, "legs": list(self.legs), "shared": self.shared}
        for name in ("centre", "half", "lo", "hi", "split", "centre2", "half2"):
            if getattr(self, name):
                d[name] = [float(v) for v in getattr(self, name)]
        if self.knots:
            d["knots"] = [[float(v) for v in row] for row in self.knots]
        if self.period:
            d["period"] = float(self.period)
        if self.harmonics > 1:
            d["harmonics"] = int(self.harmonics)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Shape:
        tup = lambda key: tuple(float(v) for v in d.get(key, ()))  # noqa: E731
        return cls(
            kind=str(d["kind"]),
            legs=tuple(int(v) for v in d.get("legs", (1, 2, 3, 4, 5, 6))),
            shared=bool(d.get("shared", False)),
            centre=tup("centre"),
            half=tup("half"),
            lo=tup("lo"),
            hi=tup("hi"),
            knots=tuple(tuple(float(v) for v in row) for row in d.get("knots", ())),
            period=float(d.get("period", 0.0)),
            split=tup("split"),
            centre2=tup("centre2"),
            half2=tup("half2"),
            harmonics=int(d.get("harmonics", 1)),
        )


def line(values: np.ndarray, shared: bool = False) -> Shape:
    """The straight line over each leg's range of ``values`` (M, 6) (the pooled range when
    ``shared``)."""
    lo, hi = _ranges(values, shared)
    half = np.maximum(0.5 * (hi - lo), 1e-12)
    return Shape("line", shared=shared, centre=_t(0.5 * (lo + hi)), half=_t(half))


def spline(values: np.ndarray, n_knots: int, shared: bool = False) -> Shape:
    """A cubic B-spline with ``n_knots`` interior knots per leg, at the quantiles of the leg's
    distinct values (M, 6): dense where the poses are, so that every basis function holds
    poses on either side of a fold (a knot where few poses are left a column held-out folds
    could not fit), and never on top of each other (a clamped leg repeats one reading over a
    whole step: its repeats count once)."""
    lo, hi = _ranges(values, shared)
    grid = np.linspace(0.0, 1.0, n_knots + 2)[1:-1]
    columns = [values.reshape(-1)] if shared else [values[:, k] for k in range(6)]
    knots = np.array(
        [np.quantile(np.unique(u), grid) if n_knots else np.zeros(0) for u in columns]
    ).reshape(len(columns), n_knots)
    if shared:
        knots = np.repeat(knots, 6, axis=0)
    return Shape("spline", shared=shared, lo=_t(lo), hi=_t(hi), knots=tuple(_t(r) for r in knots))


def periodic(period: float, shared: bool = False, harmonics: int = 1) -> Shape:
    return Shape("periodic", shared=shared, period=float(period), harmonics=int(harmonics))


def step(split: np.ndarray, shared: bool = False) -> Shape:
    return Shape("step", shared=shared, split=_t(np.broadcast_to(split, (6,))))


def hinge(values: np.ndarray, split: np.ndarray, shared: bool = False) -> Shape:
    """Two straight lines meeting at ``split`` (6,) along each leg's ``values`` (M, 6): a dead
    band, a stop reached, a V about a level — a slope that changes at one place."""
    lo, hi = _ranges(values, shared)
    half = np.maximum(0.5 * (hi - lo), 1e-12)
    return Shape(
        "hinge",
        shared=shared,
        centre=_t(0.5 * (lo + hi)),
        half=_t(half),
        split=_t(np.broadcast_to(split, (6,))),
    )


def product(factors: np.ndarray, shared: bool = False) -> Shape:
    """The bilinear surface over each leg's ranges of the two covariates ``factors``
    (M, 6, 2) (the pooled ranges when ``shared``)."""
    lo, hi = _ranges(factors[..., 0], shared)
    lo2, hi2 = _ranges(factors[..., 1], shared)
    return Shape(
        "product",
        shared=shared,
        centre=_t(0.5 * (lo + hi)),
        half=_t(np.maximum(0.5 * (hi - lo), 1e-12)),
        centre2=_t(0.5 * (lo2 + hi2)),
        half2=_t(np.maximum(0.5 * (hi2 - lo2), 1e-12)),
    )


def sign(shared: bool = False) -> Shape:
    return Shape("sign", shared=shared)


def _ranges(values: np.ndarray, shared: bool) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = values.min(axis=0), values.max(axis=0)
    if shared:
        lo, hi = np.full(6, lo.min()), np.full(6, hi.max())
    return lo, np.maximum(hi, lo + 1e-12)


def _t(a) -> tuple[float, ...]:
    return tuple(float(v) for v in np.asarray(a, float).ravel())


class ExploredEffect(Effect):
    """An effect that is a shape (:attr:`shape`) along a covariate (:attr:`covariate`): what
    the explorer found, as an effect file declares it. Its parameters are the shape's
    coefficients, µm. Subclass it in a file (``covariate = "yaw"``, ``shape = Shape(...)``),
    or override :meth:`basis` with the physics you suspect."""

    covariate: str = ""
    shape: Shape = Shape("line")
    points_at: str = ""

    def __init__(self, name: str = "", cov: str = "", shape: Shape | None = None) -> None:
        # An instance made by the explorer carries its own name, covariate and shape; a
        # subclass in an effect file declares them as class attributes.
        if name:
            self.name = name
        if cov:
            self.covariate = cov
        if shape is not None:
            self.shape = shape

    #: Evaluated at the geometry the data carry (the fit's linear seed, a calibrated model's
    #: own), not refitted with it: a shape along a geometric quantity (a leg's inclination)
    #: moves by far less than its knots' spacing between the two, and a basis that moves with
    #: each step of the fit stalled it (18 spline columns along the inclination).
    uses_geometry = False

    def params(self, robot) -> list[ParamSpec]:
        s = self.shape
        legs = ("shared",) if s.shared else tuple(f"leg{leg}" for leg in s.legs)
        return [
            ParamSpec(f"{self.name}.c{j}_{on}", "µm", PLAUSIBLE_UM, 1e-3, RESOLUTION_UM)
            for on in legs
            for j in range(1, s.per_leg + 1)
        ]

    def basis(self, data: EffectData) -> np.ndarray:
        """(M, 6, n_params) mm per µm: the shape at the covariate's values."""
        if self.shape.kind == "product":
            return 1e-3 * self.shape.basis(covariate_factors(self.covariate, data))
        return 1e-3 * self.shape.basis(covariate_values(self.covariate, data))

    def cannot_predict(self, data: EffectData) -> str | None:
        return self.missing(data)

    def missing(self, data: EffectData) -> str | None:
        pair = parse_product(self.covariate)
        for name in pair or (self.covariate,):
            why = _missing_series(name, data)
            if why:
                return why
        return None


def _missing_series(name: str, data: EffectData) -> str | None:
    """Why ``data`` cannot give the covariate ``name`` (a fixed one, a column, either through a
    lag), or None."""
    series = series_of(name)
    if series == "temperature" and data.temperature is None:
        return "the measurements have no temperature column"
    if series not in _fixed() and series not in data.columns:
        return (
            f"it follows the table's column {series!r}, which these data do not have "
            "(give the table with that column)"
        )
    return None


def _fixed() -> set[str]:
    from hexcal.effects.covariates import FIXED

    return {c.name for c in FIXED}
