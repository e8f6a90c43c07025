"""The rules a row of ``measurements.csv`` must keep (docs/formats.md), as pydantic v2 types:
:class:`MeasurementRow` validates one row of raw CSV text, and each problem is named with its
column and what to fix. :mod:`hexcal.io.measurements_csv` streams a file through them (it
checks whole blocks with numpy first, and comes here for the rows of a block that breaks one)."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Annotated, Any

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    ValidationError,
    ValidationInfo,
    field_validator,
)
from pydantic_core import PydanticCustomError

from hexcal.io.csv_dialect import grouping_hint
from hexcal.io.measurements import CONSTRAINTS, QUATERNION_COLUMNS, QUATERNION_TOLERANCE, Issue
from hexcal.io.safe_read import (
    MAX_COORDINATE_MM,
    MAX_POSE_ID,
    MAX_TEMPERATURE_C,
    MAX_TIME_S,
    MIN_TEMPERATURE_C,
)
from hexcal.vocabulary import Constraint

_ROW_HINT = "fix the value or remove the row"


# --------------------------------------------------------------------------------------------
# Row validation (pydantic)

# Error types whose message this module writes itself; pydantic's own messages get a generic hint.
_OWN_ERRORS = frozenset(
    {
        "empty_field",
        "not_a_number",
        "not_finite",
        "not_an_integer",
        "not_text",
        "leg_range",
        "unknown_constraint",
        "leg_constraint",
        "quaternion_norm",
        "out_of_range",
    }
)
_INTEGER_RE = re.compile(r"[+-]?[0-9]+(?:\.0*)?")


def _empty() -> PydanticCustomError:
    return PydanticCustomError(
        "empty_field", "the field is empty; fill in the value or remove the row"
    )


def _parse_number(value: Any) -> float:
    """A finite float from a CSV field (or a Python number)."""
    if isinstance(value, str):
        text = value.strip()
        if not text:
            raise _empty()
        # float() also takes '1_000' and non-ASCII digits; other CSV readers do not, so refuse
        # them here rather than write files only this reader understands.
        try:
            if "_" in text or not text.isascii():
                raise ValueError
            x = float(text)
        except ValueError:
            raise PydanticCustomError(
                "not_a_number", f"{text!r} is not a number{grouping_hint(text)}; {_ROW_HINT}"
            ) from None
    elif isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool):
        text, x = repr(value), float(value)
    else:
        raise PydanticCustomError("not_a_number", f"{value!r} is not a number; {_ROW_HINT}")
    if not math.isfinite(x):
        raise PydanticCustomError(
            "not_finite",
            f"{text!r} is not a finite number (NaN and infinity are not allowed); {_ROW_HINT}",
        )
    return x


def _parse_integer(value: Any) -> int:
    """An int from a CSV field; ``'3'`` and ``'3.0'`` (spreadsheet exports) are accepted."""
    if isinstance(value, str):
        text = value.strip()
        if not text:
            raise _empty()
        if not _INTEGER_RE.fullmatch(text):
            raise PydanticCustomError("not_an_integer", f"{text!r} is not an integer; {_ROW_HINT}")
        return int(text.split(".")[0])
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return int(value)
    if isinstance(value, (float, np.floating)) and math.isfinite(value) and value == int(value):
        return int(value)
    raise PydanticCustomError("not_an_integer", f"{value!r} is not an integer; {_ROW_HINT}")


def _parse_text(value: Any) -> str:
    if not isinstance(value, str):
        raise PydanticCustomError("not_text", f"{value!r} is not text; {_ROW_HINT}")
    text = value.strip()
    if not text:
        raise _empty()
    return text


def _check_leg(leg: int) -> int:
    if not 0 <= leg <= 6:
        raise PydanticCustomError(
            "leg_range",
            f"leg {leg} is outside 0..6; give the clamped leg 1..6, or 0 for a free pose",
        )
    return leg


def _check_constraint(text: str) -> str:
    if text not in CONSTRAINTS:
        case = " (constraint names are lower case)" if text.lower() in CONSTRAINTS else ""
        raise PydanticCustomError(
            "unknown_constraint",
            f"{text!r} is not a known constraint{case}; use one of: {', '.join(CONSTRAINTS)}",
        )
    return text


def _check_range(x: float, low: float, high: float, unit: str) -> float:
    if not low <= x <= high:
        raise PydanticCustomError(
            "out_of_range", f"{x!r} {unit} is outside {low:g}..{high:g} {unit}; {_ROW_HINT}"
        )
    return x


def _within(low: float, high: float, unit: str) -> AfterValidator:
    """An after-validator refusing values outside [low, high] ``unit``."""
    return AfterValidator(lambda x: _check_range(x, low, high, unit))


def _check_pose_id(pose_id: int) -> int:
    if not 1 <= pose_id <= MAX_POSE_ID:
        raise PydanticCustomError(
            "out_of_range",
            f"pose_id {pose_id} is outside 1..{MAX_POSE_ID} (2**53 - 1); renumber the poses from 1",
        )
    return pose_id


Number = Annotated[float, BeforeValidator(_parse_number)]
#: A position or reading, mm, within ±MAX_COORDINATE_MM.
Millimetres = Annotated[
    float, BeforeValidator(_parse_number), _within(-MAX_COORDINATE_MM, MAX_COORDINATE_MM, "mm")
]
#: A time, s, within ±MAX_TIME_S.
Seconds = Annotated[float, BeforeValidator(_parse_number), _within(-MAX_TIME_S, MAX_TIME_S, "s")]
Integer = Annotated[int, BeforeValidator(_parse_integer)]
PoseId = Annotated[int, BeforeValidator(_parse_integer), AfterValidator(_check_pose_id)]
Text = Annotated[str, BeforeValidator(_parse_text)]
Leg = Annotated[int, BeforeValidator(_parse_integer), AfterValidator(_check_leg)]
#: A constraint as the table writes it (a :class:`Constraint` value), kept as its text.
ConstraintText = Annotated[str, BeforeValidator(_parse_text), AfterValidator(_check_constraint)]
# Not ``Number | None``: a union would report a bad value once per member, with a mangled location.
OptionalCelsius = Annotated[
    float | None,
    BeforeValidator(lambda v: None if v is None else _parse_number(v)),
    AfterValidator(
        lambda v: (
            None if v is None else _check_range(v, MIN_TEMPERATURE_C, MAX_TEMPERATURE_C, "degC")
        )
    ),
]


class MeasurementRow(BaseModel):
    """One row of measurements.csv, validated.

    Units: ``t`` s; ``x, y, z`` mm (platform origin in the measurement frame); ``qw..qz`` unit
    quaternion, scalar first (norm within :data:`QUATERNION_TOLERANCE` of 1); ``rho1..rho6`` mm;
    ``temperature`` degC or None when the file has no such column. Fields accept the raw CSV
    strings; whitespace around them is ignored. Ranges: ``pose_id`` 1 .. 2**53 − 1; ``t``
    ±1e9 s; positions and readings ±1e6 mm; temperature −273.15..1000 degC.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    pose_id: PoseId
    t: Seconds
    step: Text
    leg: Leg
    constraint: ConstraintText
    x: Millimetres
    y: Millimetres
    z: Millimetres
    qw: Number
    qx: Number
    qy: Number
    qz: Number
    rho1: Millimetres
    rho2: Millimetres
    rho3: Millimetres
    rho4: Millimetres
    rho5: Millimetres
    rho6: Millimetres
    temperature: OptionalCelsius = None

    # Field validators rather than one model validator: a row that breaks both rules reports
    # both, and each is pinned to a column. ``leg`` precedes ``constraint`` and ``qw..qy``
    # precede ``qz``, so ``info.data`` holds them when they were valid.
    @field_validator("constraint")
    @classmethod
    def _leg_matches_constraint(cls, constraint: str, info: ValidationInfo) -> str:
        leg = info.data.get("leg")
        if leg is None:
            return constraint
        if leg == 0 and constraint != Constraint.FREE:
            raise PydanticCustomError(
                "leg_constraint",
                f"constraint '{constraint}' needs a clamped leg but leg is 0; set leg to the "
                "clamped leg (1..6), or the constraint to 'free' for a free pose",
            )
        if leg != 0 and constraint == Constraint.FREE:
            raise PydanticCustomError(
                "leg_constraint",
                f"constraint 'free' is for free poses, which have leg 0, but leg is {leg}; set "
                "leg to 0, or the constraint to the clamp used (direction, direction+length, "
                "length)",
            )
        return constraint

    @field_validator("qz")
    @classmethod
    def _unit_quaternion(cls, qz: float, info: ValidationInfo) -> float:
        parts = [info.data.get(c) for c in QUATERNION_COLUMNS[:3]]
        if any(p is None for p in parts):
            return qz
        q = (*(float(p) for p in parts if p is not None), qz)
        norm = math.sqrt(sum(c * c for c in q))
        if abs(norm - 1.0) > QUATERNION_TOLERANCE:
            raise PydanticCustomError(
                "quaternion_norm",
                f"quaternion (qw, qx, qy, qz) = ({', '.join(repr(c) for c in q)}) has norm "
                f"{norm:.6f}, not within {QUATERNION_TOLERANCE:g} of 1; check the column order "
                "(scalar first) or renormalise at the source, or remove the row",
                {"column": "qw"},
            )
        return qz


def row_issues(exc: ValidationError, line: int, values: Mapping[str, str]) -> list[Issue]:
    issues = []
    for err in exc.errors(include_url=False):
        ctx = err.get("ctx") or {}
        column = ctx.get("column") or (str(err["loc"][0]) if err["loc"] else None)
        if err["type"] in _OWN_ERRORS:
            message = err["msg"]
        else:
            message = f"{values.get(column or '', '')!r}: {err['msg']}; {_ROW_HINT}"
        issues.append(Issue(message, line=line, column=column))
    return issues
