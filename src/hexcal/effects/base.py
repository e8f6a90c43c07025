"""What an effect is, the data it may use, and the registry of effects by name."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from hexcal.model.robot import Robot


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
        )


class Effect(ABC):
    """One physical effect: contribution to the geometric length = ``basis(data) @ θ``.

    Subclasses set ``name``, ``physics`` (one sentence), ``needs`` (what the data must hold),
    ``separating_motion`` (the poses that tell it from the geometry), and implement
    :meth:`params` and :meth:`basis`.
    """

    name: str = ""
    physics: str = ""
    needs: tuple[str, ...] = ()
    separating_motion: str = ""
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

    def contribution(self, data: EffectData, values: np.ndarray) -> np.ndarray:
        """(M, 6) mm extra length for parameter values in their spec units."""
        return self.basis(data) @ np.asarray(values, float)

    def meaning(self, name: str, value: float, robot: Robot) -> str:
        """What a value of parameter ``name`` outside its plausible range means physically and
        what to check (one clause, no final stop). ``value`` is in the spec's unit (offsets:
        the fitted offset itself, not its departure from the design)."""
        return "a value this hardware should not have — check the data and the robot description"


CATALOGUE: dict[str, Effect] = {}


def register(cls: type[Effect]) -> type[Effect]:
    """Class decorator: add an effect to the catalogue under its ``name``."""
    inst = cls()
    if not inst.name or inst.name in CATALOGUE:
        raise ValueError(f"effect name {inst.name!r} is empty or already registered")
    CATALOGUE[inst.name] = inst
    return cls


def get_effect(name: str) -> Effect:
    """The registered effect called ``name``; a clear error lists the catalogue otherwise."""
    try:
        return CATALOGUE[name]
    except KeyError:
        raise ValueError(
            f"unknown effect {name!r}; the catalogue has: {', '.join(sorted(CATALOGUE))}"
        ) from None


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
