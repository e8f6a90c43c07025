"""What an effect is, the data it may use, and the registry of effects by name.

This module is hexcal's public **Effect API**, version :data:`API_VERSION` (docs/effects.md):
:class:`Effect`, :class:`EffectData`, :class:`ParamSpec`, :func:`register` and
:func:`diagonal` are stable for every effect written against it, inside hexcal's catalogue or
outside it (an installed package's entry point in the group ``hexcal.effects``, or a Python
file the user names with ``--effects``; :mod:`hexcal.effects.plugins`). An effect from outside
is held to the contract when it is used: its parameters' names, units and ranges, and its
basis' shape and finiteness, are checked, and a failure names the effect and where it came from.
"""

from __future__ import annotations

import contextlib
import functools
import math
import re
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any, Literal

import numpy as np

from hexcal.errors import InputError
from hexcal.model.robot import Robot

#: The version of the Effect API. An effect declares the version it was written for
#: (:attr:`Effect.api_version`); one written for a later version than this hexcal provides is
#: refused with "upgrade hexcal". Additions that leave existing effects working keep the version.
API_VERSION = 1


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: prefixed name (``gain.g3``), unit, plausible range in that unit, and the
    factor from the unit to the model's internal value (e.g. ppm → 1e-6).

    ``plausible`` is a prior: the range real hardware of this kind stays within. The catalogue's
    defaults can be replaced per robot (robot.json ``plausible``, see :func:`with_priors`); a
    fitted value outside it is flagged with what it means, never taken as a verdict.
    ``resolution`` (in the unit) is the standard error at which the data resolve the parameter:
    identifiability is judged against it, so that widening a prior for loose hardware does not
    loosen what counts as separable. None: a tenth of the plausible half-width.
    """

    name: str
    unit: str
    plausible: tuple[float, float]
    scale: float = 1.0
    resolution: float | None = None


@dataclass(frozen=True)
class EffectData:
    """What effects may depend on, for M poses in recording order.

    readings (M, 6) mm; position (M, 3) mm; rotation (M, 3, 3); t (M,) s; temperature (M,) degC
    or None; robot: the design (pitch, mass, offsets); a, b (6, 3) mm: the geometry at which
    geometry-dependent quantities (leg forces, lengths) are evaluated — the linear seed.
    """

    readings: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    t: np.ndarray
    temperature: np.ndarray | None
    robot: Robot
    a: np.ndarray
    b: np.ndarray
    extras: dict = field(default_factory=dict)
    #: The measurement table's extra numeric columns by name, (M,) each: a lab's own sensors
    #: (:func:`hexcal.effects.covariates.numeric_columns`)
    columns: dict[str, np.ndarray] = field(default_factory=dict)
    #: (M,) the procedure step of each pose (the table's ``step``, e.g. "leg3-direction"), or
    #: None where the poses come from no procedure (a prediction's)
    step: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.readings)

    @cached_property
    def leg_vectors(self) -> np.ndarray:
        """(M, 6, 3) mm, ``P + R b_k − a_k`` at the evaluation geometry."""
        return (
            self.position[:, None, :]
            + np.einsum("mij,kj->mki", self.rotation, self.b)
            - self.a[None]
        )

    @cached_property
    def lengths(self) -> np.ndarray:
        """(M, 6) mm geometric lengths at the evaluation geometry."""
        return np.linalg.norm(self.leg_vectors, axis=-1)

    def at_geometry(self, robot: Robot) -> EffectData:
        """The same poses with the geometry (and offsets, pitch, mass) of ``robot``."""
        return EffectData(
            self.readings,
            self.position,
            self.rotation,
            self.t,
            self.temperature,
            robot,
            robot.a,
            robot.b,
            self.extras,
            self.columns,
            self.step,
        )

    def subset(self, idx: np.ndarray) -> EffectData:
        t = None if self.temperature is None else self.temperature[idx]
        return EffectData(
            self.readings[idx],
            self.position[idx],
            self.rotation[idx],
            self.t[idx],
            t,
            self.robot,
            self.a,
            self.b,
            self.extras,
            {k: v[idx] for k, v in self.columns.items()},
            None if self.step is None else self.step[idx],
        )


class EffectError(InputError):
    """An effect from outside the catalogue breaks the Effect API, or cannot be loaded; the
    message names the effect, where it came from, and what to fix."""


@dataclass(frozen=True)
class EffectSource:
    """Where an effect comes from: hexcal's ``catalogue``; an installed ``package`` (its
    distribution name, version and entry point); a ``file`` named with ``--effects`` (its name
    and the SHA-256 of the bytes that ran); or a ``module`` of the program that registered it."""

    kind: Literal["catalogue", "package", "file", "module"]
    package: str = ""
    version: str = ""
    entry_point: str = ""
    file: str = ""
    sha256: str = ""
    module: str = ""

    def text(self) -> str:
        """One phrase: ``package hexcal-legsag 0.1.0``, ``file legsag.py (SHA-256 1a2b3c4d…)``."""
        if self.kind == "package":
            return f"package {self.package} {self.version}".rstrip()
        if self.kind == "file":
            return f"file {self.file} (SHA-256 {self.sha256[:12]}…)"
        if self.kind == "module":
            return f"module {self.module}"
        return "hexcal's catalogue"

    def how_to_get(self) -> str:
        """What the user must do to make the effect available again."""
        if self.kind == "package":
            pin = f"=={self.version}" if self.version else ""
            return f"install it (pip install '{self.package}{pin}')"
        if self.kind == "file":
            return f"pass --effects {self.file} (the file whose SHA-256 is {self.sha256})"
        if self.kind == "module":
            return f"import {self.module}, which registers it, before loading the model"
        return "upgrade hexcal"


#: The source of the catalogue's own effects (modules of this package).
CATALOGUE_SOURCE = EffectSource("catalogue")
_CATALOGUE_PACKAGE = __name__.rsplit(".", 1)[0] + "."
#: Set while :mod:`hexcal.effects.plugins` imports a package or runs a file: what registers
#: then comes from there.
_loading: list[EffectSource] = []


@contextlib.contextmanager
def loading_from(source: EffectSource) -> Iterator[None]:
    """Effects registered inside the block come from ``source`` (the plugin loader's use)."""
    _loading.append(source)
    try:
        yield
    finally:
        _loading.pop()


class Effect(ABC):
    """One physical effect: contribution to the geometric length = ``basis(data) @ θ``.

    The contribution is what the effect adds to ``reading + offset`` to give the ideal
    geometric length ``|P + R b_k − a_k|`` (mm). Subclasses set ``name`` (lower case: letters,
    digits, ``_`` or ``-``; the command line's vocabulary), ``physics`` (one sentence), ``needs``
    (what the data must hold), ``separating_motion`` (the poses that tell it from the geometry),
    and implement :meth:`params` and :meth:`basis`. Optional: :meth:`missing`,
    :meth:`cannot_predict`, :meth:`meaning`, :meth:`look_alike`, :meth:`typical_values`,
    :meth:`true_contribution`, and the flags ``uses_geometry`` and ``of_the_session``.
    """

    name: str = ""
    physics: str = ""
    needs: tuple[str, ...] = ()
    separating_motion: str = ""
    #: The Effect API version the effect was written for (:data:`API_VERSION`).
    api_version: int = API_VERSION
    #: Where the effect comes from; set by :func:`register`.
    source: EffectSource = CATALOGUE_SOURCE
    #: The basis depends on the robot's geometry (``data.a``, ``data.b`` or its offsets), so a
    #: fit evaluates it at the fitted geometry and a calibrated model at its own: both then
    #: predict the same lengths.
    uses_geometry: bool = False
    #: A property of the session (a tracker drifting), not of the robot: fitted with the
    #: geometry, but left out of the calibrated model that is shipped and predicts.
    of_the_session: bool = False

    @abstractmethod
    def params(self, robot: Robot) -> list[ParamSpec]:
        """The parameters, in the order of the basis columns."""

    @abstractmethod
    def basis(self, data: EffectData) -> np.ndarray:
        """(M, 6, p) mm per unit of each parameter (in the spec's unit × scale)."""

    def missing(self, data: EffectData) -> str | None:
        """Why these data cannot carry the effect (None when they can)."""
        return None

    def cannot_predict(self, data: EffectData) -> str | None:
        """Why a calibrated model cannot evaluate this effect on these data (a missing input,
        not a lack of information as in :meth:`missing`); None when it can."""
        return None

    def unknown(self, data: EffectData) -> np.ndarray | None:
        """(M, 6) bool: the readings whose contribution these data leave undetermined — the
        state the effect depends on was set before the session began (a leg that has not moved
        yet rests on an unknown side of its play) — or None when every one is known. A model
        is not judged on them (``hexcal validate`` leaves their poses out of its verdict, and
        says so with :attr:`unknown_why`)."""
        return None

    #: Why :meth:`unknown` readings cannot be known (a clause, for the note that names them).
    unknown_why: str = ""

    def contribution(self, data: EffectData, values: np.ndarray) -> np.ndarray:
        """(M, 6) mm extra length for parameter values in their spec units."""
        return self.basis(data) @ np.asarray(values, float)

    def meaning(self, name: str, value: float, robot: Robot) -> str:
        """What a value of parameter ``name`` outside its plausible range means physically and
        what to check (one clause, no final stop). ``value`` is in the spec's unit (offsets:
        the fitted offset itself, not its departure from the design)."""
        return "a value this hardware should not have — check the data and the robot description"

    def look_alike(self, values: np.ndarray, robot: Robot) -> str:
        """What else would leave the same residual as this effect with fitted ``values`` (in
        the specs' units), and what measurement separates them; said when the diagnosis names
        the effect. Empty when nothing known looks alike."""
        return ""

    def typical_values(self, rng: np.random.Generator, robot: Robot) -> np.ndarray | None:
        """Parameter values (in the specs' units) at a size real hardware shows, drawn from
        ``rng``: what ``hexcal simulate --effect`` hides. None: the effect gives none."""
        return None

    def true_contribution(self, data: EffectData, values: np.ndarray) -> np.ndarray:
        """(M, 6) mm the simulator adds for ``values``: the model's own linear
        :meth:`contribution`, unless the effect is linearised from an exact law, which it gives
        here (a simulated session then tests the linearisation too)."""
        return self.contribution(data, values)

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        # An effect from outside hexcal is held to the contract where it is used: its specs
        # and basis are checked, and its failures name it and its source.
        if cls.__module__.startswith(_CATALOGUE_PACKAGE):
            return
        if "params" in cls.__dict__:
            setattr(cls, "params", _checked_params(cls.__dict__["params"]))  # noqa: B010
        if "basis" in cls.__dict__:
            setattr(cls, "basis", _checked_basis(cls.__dict__["basis"]))  # noqa: B010


def _who(effect: Effect) -> str:
    return f"effect {effect.name!r} (from {effect.source.text()})"


def _failure(effect: Effect, what: str, exc: Exception) -> EffectError:
    return EffectError(
        f"{_who(effect)}: {what} failed: {type(exc).__name__}: {exc}; this is a fault in the "
        "effect's code: fix it there (docs/effects.md says what each method must return)"
    )


def _checked_params(method: Callable[..., Any]) -> Callable[..., list[ParamSpec]]:
    @functools.wraps(method)
    def params(self: Effect, robot: Robot) -> list[ParamSpec]:
        try:
            specs = list(method(self, robot))
        except InputError:
            raise
        except Exception as exc:
            raise _failure(self, "params()", exc) from exc
        check_specs(self, specs)
        # robot.json's plausible ranges apply to every effect, whether or not its code asks.
        return with_priors(self.name, specs, robot)

    return params


def _checked_basis(method: Callable[..., Any]) -> Callable[..., np.ndarray]:
    @functools.wraps(method)
    def basis(self: Effect, data: EffectData) -> np.ndarray:
        try:
            out = np.asarray(method(self, data), dtype=float)
        except InputError:
            raise
        except Exception as exc:
            raise _failure(self, "basis()", exc) from exc
        p = len(self.params(data.robot))
        if out.shape != (len(data), 6, p):
            raise EffectError(
                f"{_who(self)}: basis() gave an array of shape {out.shape}; it must be "
                f"({len(data)}, 6, {p}): poses × legs × one column per parameter"
            )
        if not np.isfinite(out).all():
            raise EffectError(
                f"{_who(self)}: basis() gave a NaN or infinite value; every entry must be a "
                "finite length (mm per unit of the parameter)"
            )
        return out

    return basis


def check_specs(effect: Effect, specs: list[ParamSpec]) -> None:
    """Refuse (:class:`EffectError`) parameters that break the API: each a :class:`ParamSpec`
    named ``<effect>.<symbol>``, names distinct, a unit, a finite plausible range with low <
    high, a positive finite scale and resolution."""
    problems = []
    seen: set[str] = set()
    prefix = f"{effect.name}."
    if not specs:
        problems.append("params() gave no parameter")
    for i, s in enumerate(specs):
        if not isinstance(s, ParamSpec):
            problems.append(f"parameter {i} is a {type(s).__name__}, not a ParamSpec")
            continue
        if not (s.name.startswith(prefix) and len(s.name) > len(prefix)):
            problems.append(f"parameter {s.name!r} must be named {prefix}<symbol>")
        if s.name in seen:
            problems.append(f"parameter {s.name!r} appears twice")
        seen.add(s.name)
        if not s.unit:
            problems.append(f"parameter {s.name!r} has no unit")
        lo, hi = s.plausible
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            problems.append(f"parameter {s.name!r} has plausible {s.plausible}: give [low, high]")
        if not (math.isfinite(s.scale) and s.scale > 0):
            problems.append(f"parameter {s.name!r} has scale {s.scale}: give a positive factor")
        r = s.resolution
        if r is not None and not (math.isfinite(r) and r > 0):
            problems.append(f"parameter {s.name!r} has resolution {r}: give a positive number")
    if problems:
        raise EffectError(f"{_who(effect)}: " + "; ".join(problems))


CATALOGUE: dict[str, Effect] = {}

#: An effect's name: what ``--add`` takes and what prefixes its parameters.
NAME = re.compile(r"[a-z][a-z0-9_-]{0,39}")
#: Names an effect cannot take: the verdicts that name no effect.
RESERVED = frozenset({"none", "unexplained", "outliers"})


def register(cls: type[Effect]) -> type[Effect]:
    """Class decorator: add an effect to the registry under its ``name``, with where it comes
    from (hexcal's catalogue, the package or file being loaded, or the module defining it)."""
    if not (isinstance(cls, type) and issubclass(cls, Effect)):
        raise EffectError(f"@register takes a subclass of hexcal.effects.Effect, not {cls!r}")
    if _loading:
        source = _loading[-1]
    elif cls.__module__.startswith(_CATALOGUE_PACKAGE):
        source = CATALOGUE_SOURCE
    else:
        source = EffectSource("module", module=cls.__module__)
    where = f"{cls.__name__} (from {source.text()})"
    version = getattr(cls, "api_version", API_VERSION)
    if not isinstance(version, int) or version > API_VERSION:
        raise EffectError(
            f"{where} is written for the Effect API version {version!r}; this hexcal provides "
            f"version {API_VERSION}: upgrade hexcal"
        )
    name = getattr(cls, "name", "")
    if not isinstance(name, str) or not NAME.fullmatch(name) or name in RESERVED:
        raise EffectError(
            f"{where}: name {name!r} is not an effect name: give 1–40 lower-case letters, "
            "digits, '_' or '-', starting with a letter (not none, unexplained or outliers)"
        )
    if name in CATALOGUE:
        raise EffectError(
            f"{where}: effect name {name!r} is taken already, by {CATALOGUE[name].source.text()}; "
            "give the new effect another name"
        )
    for attr in ("physics", "separating_motion"):
        if not isinstance(getattr(cls, attr, ""), str) or not getattr(cls, attr, ""):
            raise EffectError(
                f"{where}: set {attr} (one sentence: "
                + ("the effect's physics" if attr == "physics" else "the motion that separates it")
                + ")"
            )
    try:
        inst = cls()
    except Exception as exc:
        raise EffectError(f"{where}: could not be created ({type(exc).__name__}: {exc})") from exc
    inst.source = source
    CATALOGUE[name] = inst
    return cls


def get_effect(name: str) -> Effect:
    """The registered effect called ``name``; a clear error lists the registered ones (and says
    how an effect from outside the catalogue is made available) otherwise."""
    try:
        return CATALOGUE[name]
    except KeyError:
        raise EffectError(
            f"unknown effect {name!r}; {unavailable(name)}the catalogue has: "
            f"{', '.join(sorted(CATALOGUE))}"
        ) from None


#: An installed effect's name (its entry point's) → why its package failed to load; filled by
#: :mod:`hexcal.effects.plugins`.
FAILED_PACKAGES: dict[str, str] = {}


def unavailable(name: str) -> str:
    """Why ``name`` is not registered, as the start of a sentence (empty when nothing is known
    beyond its absence): an installed package that failed, or how outside effects are given."""
    if name in FAILED_PACKAGES:
        return f"{FAILED_PACKAGES[name]}; "
    return (
        "an effect from outside the catalogue is known once its package is installed, or its "
        "file given with --effects FILE.py; "
    )


def source_of(name: str) -> EffectSource:
    """Where the registered effect ``name`` comes from."""
    return get_effect(name).source


def per_leg(
    prefix: str,
    symbol: str,
    unit: str,
    plausible: tuple[float, float],
    scale: float = 1.0,
    resolution: float | None = None,
) -> list[ParamSpec]:
    """Six parameters ``prefix.symbol1`` … ``prefix.symbol6``."""
    return [
        ParamSpec(f"{prefix}.{symbol}{k}", unit, plausible, scale, resolution) for k in range(1, 7)
    ]


def with_priors(effect: str, specs: list[ParamSpec], robot: Robot | None) -> list[ParamSpec]:
    """``specs`` with the plausible ranges robot.json states (key ``plausible``): a parameter's
    own entry (its full name, e.g. ``gain.g1``) wins over its effect's (``gain``), which wins
    over the catalogue's default. Every effect's :meth:`Effect.params` passes its specs through
    this, so the fit's flags and everything else that reads a spec see the robot's priors."""
    table = getattr(robot, "plausible", None) or {}
    if not table:
        return specs
    out = []
    for s in specs:
        rng = table.get(s.name, table.get(effect))
        out.append(s if rng is None else replace(s, plausible=(float(rng[0]), float(rng[1]))))
    return out


def leg_of(name: str) -> int:
    """The leg (1..6) a per-leg parameter belongs to, by its name's last digit."""
    return int(name[-1])


def diagonal(values: np.ndarray) -> np.ndarray:
    """(M, 6) per-leg values → (M, 6, 6) basis with each leg's value in its own column."""
    out = np.zeros((*values.shape, 6))
    idx = np.arange(6)
    out[:, idx, idx] = values
    return out
