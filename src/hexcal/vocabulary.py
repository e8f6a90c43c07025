"""hexcal's vocabulary as types: the constraint of a step, the verdict of a diagnosis, the model.

- :class:`Constraint` — how a step clamps its leg: ``direction``, ``direction+length``,
  ``length``, or ``free`` (nothing clamped).
- :class:`Outcome` and :data:`Verdict` — a diagnosis' verdict is either a fixed outcome
  (``none``, ``unexplained``, ``outliers``, ``noise_understated``) or the name of the
  catalogue effect that is missing (``gain``, ``backlash``...); :func:`verdict_of`,
  :func:`is_effect` and :func:`names_an_addition` tell them apart.
- :class:`ModelKind` — the geometric model: 36 parameters (the drawing's leg offsets) or 42
  (the offsets fitted too).

The string enums are ``str`` and the model an ``int``: they compare equal to, hash like, print
as and serialize (JSON, CSV, pydantic) to their plain values, so files, the command line and
user code that pass ``"direction"`` or ``42`` keep working. The pydantic field types
(:data:`ConstraintField`, :data:`ModelKindField`) accept exactly what the ``Literal`` types they
replace accepted, with the same messages for a bad value.
"""

from __future__ import annotations

from enum import Enum, IntEnum
from typing import Annotated, Any, TypeAlias

from pydantic import PlainSerializer, PlainValidator, WithJsonSchema
from pydantic_core import PydanticCustomError


class Constraint(str, Enum):
    """How a step clamps its leg (the ``constraint`` column of a measurement table)."""

    DIRECTION = "direction"  #: Type I: the leg's direction is clamped
    DIRECTION_LENGTH = "direction+length"  #: Type II: its direction and length
    LENGTH = "length"  #: Type III: its length
    FREE = "free"  #: nothing clamped

    def __str__(self) -> str:
        return self.value

    def __format__(self, spec: str) -> str:
        return format(self.value, spec)

    @property
    def clamps_length(self) -> bool:
        """The clamp holds the leg's length (``direction+length``, ``length``)."""
        return self in (Constraint.DIRECTION_LENGTH, Constraint.LENGTH)

    @property
    def clamps_direction(self) -> bool:
        """The clamp holds the leg's direction (``direction``, ``direction+length``)."""
        return self in (Constraint.DIRECTION, Constraint.DIRECTION_LENGTH)


#: The constraints a leg is clamped with (every constraint but ``free``), in table order.
LEG_CONSTRAINTS = (Constraint.DIRECTION, Constraint.DIRECTION_LENGTH, Constraint.LENGTH)


class Outcome(str, Enum):
    """The verdicts of a diagnosis that name no catalogue effect."""

    NONE = "none"  #: nothing missing: the model is at the noise floor
    UNEXPLAINED = "unexplained"  #: an excess over the floor no catalogue effect explains
    OUTLIERS = "outliers"  #: gross outliers are the whole story
    #: the excess is spread evenly over legs, steps, time and covariates: the stated noise
    #: looks too low
    NOISE_UNDERSTATED = "noise_understated"

    def __str__(self) -> str:
        return self.value

    def __format__(self, spec: str) -> str:
        return format(self.value, spec)


#: A diagnosis' verdict: an :class:`Outcome`, or the name of the missing catalogue effect.
#: It is a ``str`` either way (an :class:`Outcome` is one), so it prints and serializes as its
#: name; the effect's name is open-ended, as the catalogue is.
Verdict: TypeAlias = Outcome | str

_OUTCOMES = {o.value: o for o in Outcome}


def verdict_of(name: str) -> Verdict:
    """The verdict named ``name``: its :class:`Outcome`, or the effect's name as it is."""
    return _OUTCOMES.get(name, name)


def is_effect(verdict: str) -> bool:
    """The verdict names a catalogue effect (it is no :class:`Outcome`)."""
    return verdict not in _OUTCOMES


def names_an_addition(verdict: str) -> bool:
    """The verdict names something to add to the model and diagnose again: an effect, or the
    outliers to acknowledge (``--add outliers``); not ``none``, ``unexplained`` nor
    ``noise_understated``."""
    return verdict not in (Outcome.NONE, Outcome.UNEXPLAINED, Outcome.NOISE_UNDERSTATED)


class ModelKind(IntEnum):
    """The geometric model: the 36 joint coordinates with the drawing's leg offsets, or 42 with
    the offsets fitted too."""

    M36 = 36
    M42 = 42

    def __str__(self) -> str:
        return str(self.value)

    def __format__(self, spec: str) -> str:
        return format(self.value, spec)


def _as_literal(kind: type[Enum], refused: tuple[type, ...]) -> PlainValidator:
    """Validate a field of enum ``kind`` as the ``Literal`` of its values it replaces: the same
    inputs accepted (a value, an equal number such as ``42.0``, the member; not ``"42"`` for 42
    nor ``b"free"``: the ``refused`` types) and the same message for a bad one."""
    members: dict[Any, Any] = {m.value: m for m in kind}
    values = [repr(v) for v in members]
    expected = ", ".join(values[:-1]) + " or " + values[-1]

    def check(value: Any) -> Any:
        if isinstance(value, kind):
            return value
        if not isinstance(value, (bool, *refused)):
            try:
                return members[value]
            except (KeyError, TypeError):  # not a value, or unhashable
                pass
        raise PydanticCustomError(
            "literal_error", "Input should be {expected}", {"expected": expected}
        )

    return PlainValidator(check)


def _values_schema(kind: type[Enum], json_type: str) -> WithJsonSchema:
    """The JSON Schema of the ``Literal`` of the values, inline and titled by the field, as
    before the enum: ``hexcal schema`` is unchanged."""
    return WithJsonSchema({"enum": [m.value for m in kind], "type": json_type})


#: Dumped as the plain value, in Python mode too: a dump is what it was with the ``Literal``.
_AS_VALUE = PlainSerializer(lambda member: member.value)

#: A pydantic field holding a :class:`Constraint` (given as its value or the member).
ConstraintField = Annotated[
    Constraint,
    _as_literal(Constraint, (bytes, bytearray)),
    _AS_VALUE,
    _values_schema(Constraint, "string"),
]
#: A pydantic field holding a :class:`ModelKind` (given as 36/42 or the member).
ModelKindField = Annotated[
    ModelKind,
    _as_literal(ModelKind, (str, bytes, bytearray)),
    _AS_VALUE,
    _values_schema(ModelKind, "integer"),
]


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """``n`` and its noun, singular for one: "1 pose", "0 poses", "12 poses" (``plural``:
    when adding "s" is wrong)."""
    return f"{n} {noun if n == 1 else (plural or noun + 's')}"
