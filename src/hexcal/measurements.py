"""The measurement table (``measurements.csv`` of docs/formats.md): read, validate, write.

One row per recorded pose: its id, time (s), procedure step, the clamped leg (1..6, 0 for a free
pose) and the constraint applied, the platform pose from the tracker (position mm, unit
quaternion scalar first) and the six encoder readings (mm), optionally the structure temperature
(degC). Extra columns are carried through untouched.

Reading streams the file row by row into typed arrays, so memory stays about the file's size
(a 200 MB table reads in well under 1 GB); rows are checked a block at a time against the rules
of :class:`MeasurementRow` (pydantic v2), which validates every row of a block that breaks one,
so that *all* bad rows are reported in one :class:`MeasurementError` naming the file, the line
and the column. Values are held to the ranges of :mod:`hexcal.safe_read` (positions and
readings ±1 km, times ±1e9 s, temperatures −273.15..1000 degC, pose ids 1 .. 2**53 − 1).
Writing is lossless:
floats are written with ``repr`` (shortest round-trip form), the column order is kept, and
``read_measurements(p)`` after ``write_measurements(m, p)`` equals ``m`` exactly.
"""

from __future__ import annotations

import codecs
import csv
import io
import math
import operator
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
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
from scipy.spatial.transform import Rotation

from hexcal.fileio import write_text_atomic
from hexcal.safe_read import (
    MAX_COORDINATE_MM,
    MAX_POSE_ID,
    MAX_TEMPERATURE_C,
    MAX_TIME_S,
    MIN_TEMPERATURE_C,
    open_binary,
)

#: Type I, Type II, Type III, and no constraint.
CONSTRAINTS = ("direction", "direction+length", "length", "free")
POSITION_COLUMNS = ("x", "y", "z")
QUATERNION_COLUMNS = ("qw", "qx", "qy", "qz")
READING_COLUMNS = ("rho1", "rho2", "rho3", "rho4", "rho5", "rho6")
REQUIRED_COLUMNS = (
    "pose_id",
    "t",
    "step",
    "leg",
    "constraint",
    *POSITION_COLUMNS,
    *QUATERNION_COLUMNS,
    *READING_COLUMNS,
)
OPTIONAL_COLUMNS = ("temperature",)
#: A stored quaternion whose norm differs from 1 by more than this is rejected: rounding to the
#: 9 digits a tracker exports stays far below it, a wrong column order or a missing sign does not.
QUATERNION_TOLERANCE = 1e-3
#: At most this many problems are spelled out in one error; the rest are counted.
MAX_MESSAGES = 20

_KNOWN_COLUMNS = frozenset(REQUIRED_COLUMNS + OPTIONAL_COLUMNS)
_FLOAT_COLUMNS = ("t", *POSITION_COLUMNS, *QUATERNION_COLUMNS, *READING_COLUMNS)
_ROW_HINT = "fix the value or remove the row"


# --------------------------------------------------------------------------------------------
# Errors


@dataclass(frozen=True)
class Issue:
    """One problem found in a measurement table.

    ``line`` is the 1-based line in the file (header = line 1); ``row`` the 0-based index for
    data that never came from a file (e.g. :meth:`Measurements.from_arrays`).
    """

    message: str
    line: int | None = None
    column: str | None = None
    row: int | None = None

    def render(self, path: str | None) -> str:
        """``"<file>: line 17, column 'qw': <message>"``."""
        where = []
        if self.line is not None:
            where.append(f"line {self.line}")
        elif self.row is not None:
            where.append(f"index {self.row}")
        if self.column is not None:
            where.append(f"column '{self.column}'")
        head = path if path is not None else "measurements"
        if where:
            head = f"{head}: {', '.join(where)}"
        return f"{head}: {self.message}"


class MeasurementError(ValueError):
    """A measurement table could not be read (or a :class:`Measurements` is inconsistent).

    The message holds one line per problem, each naming the file, the line (1-based, header =
    line 1) and the column, and saying what to do. ``path``, ``line`` and ``column`` are those of
    the first problem; ``issues`` holds every problem spelled out in the message.
    """

    def __init__(
        self, issues: Sequence[Issue], path: str | Path | None = None, *, omitted: int = 0
    ):
        if not issues:
            raise ValueError("MeasurementError needs at least one issue")
        self.path: str | None = None if path is None else str(path)
        self.issues: tuple[Issue, ...] = tuple(issues)
        self.line: int | None = self.issues[0].line
        self.column: str | None = self.issues[0].column
        lines = [issue.render(self.path) for issue in self.issues]
        if omitted > 0:
            head = self.path if self.path is not None else "measurements"
            lines.append(f"{head}: ... and {omitted} more problem(s); fix those above and retry")
        super().__init__("\n".join(lines))

    @classmethod
    def single(
        cls, path: str | Path | None, line: int | None, column: str | None, message: str
    ) -> MeasurementError:
        """An error with one problem."""
        return cls([Issue(message, line=line, column=column)], path)


def _raise_issues(issues: list[Issue], path: str | Path | None) -> None:
    if issues:
        raise MeasurementError(
            issues[:MAX_MESSAGES], path, omitted=max(0, len(issues) - MAX_MESSAGES)
        )


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
                "not_a_number", f"{text!r} is not a number; {_ROW_HINT}"
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
Constraint = Annotated[str, BeforeValidator(_parse_text), AfterValidator(_check_constraint)]
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
    constraint: Constraint
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
        if leg == 0 and constraint != "free":
            raise PydanticCustomError(
                "leg_constraint",
                f"constraint '{constraint}' needs a clamped leg but leg is 0; set leg to the "
                "clamped leg (1..6), or the constraint to 'free' for a free pose",
            )
        if leg != 0 and constraint == "free":
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
        q = (*parts, qz)
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


def _row_issues(exc: ValidationError, line: int, values: Mapping[str, str]) -> list[Issue]:
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


# --------------------------------------------------------------------------------------------
# The table in memory


def _object_array(values: Sequence[Any]) -> np.ndarray:
    # Filling a preallocated object array keeps it 1-D whatever the elements are.
    out = np.empty(len(values), dtype=object)
    out[:] = list(values)
    return out


def _to_text(value: Any) -> str:
    """Text of one extra/step value: strings as they are, floats in round-trip form."""
    if isinstance(value, str):
        return value
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return str(int(value))
    return str(value)


def _text_array(name: str, value: Any, n: int) -> np.ndarray:
    a = np.asarray(value, dtype=object)
    if a.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {a.shape}")
    values = a.tolist()
    if all(type(v) is str for v in values):  # the common case, e.g. a table just read
        return _object_array(values)
    return _object_array([_to_text(v) for v in values])


def _float_array(name: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    a = np.asarray(value, dtype=float)
    if a.size == 0 and len(shape) == 2:
        a = a.reshape(0, shape[1])
    if a.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {a.shape}")
    return a


def _as_int(v: Any) -> int:
    if isinstance(v, (bool, np.bool_)):
        raise TypeError("a boolean is not an integer")
    if isinstance(v, (float, np.floating)):
        if not (math.isfinite(v) and v == int(v)):
            raise ValueError("not an integer")
        return int(v)
    return operator.index(v)


def _int_array(name: str, value: Any, n: int) -> np.ndarray:
    a = np.asarray(value)
    if a.size == 0:
        a = a.reshape(0).astype(np.int64)
    if a.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {a.shape}")
    bounds = f"{name} must hold integers within ±2**63"
    if a.dtype.kind == "i":
        return a.astype(np.int64)
    if a.dtype.kind == "u":
        if a.size and int(a.max()) > np.iinfo(np.int64).max:
            raise ValueError(bounds)
        return a.astype(np.int64)
    if a.dtype.kind == "O":
        # Python ints beyond int64 would wrap silently in astype: convert one by one, checked.
        try:
            ints = [_as_int(v) for v in a.tolist()]
        except (TypeError, ValueError):
            raise ValueError(f"{name} must hold integers") from None
        try:
            return np.array(ints, dtype=np.int64).reshape(n)
        except OverflowError:
            raise ValueError(bounds) from None
    try:
        f = a.astype(float)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} must hold integers") from None
    if not (np.all(np.isfinite(f)) and np.all(f == np.round(f))):
        raise ValueError(f"{name} must hold integers")
    if np.any(np.abs(f) >= 2.0**63):
        raise ValueError(bounds)
    return f.astype(np.int64)


def _value_issues(m: Measurements) -> list[Issue]:
    """The row rules of :class:`MeasurementRow`, vectorised, for data not read from a file."""
    issues: list[Issue] = []

    def add(rows: np.ndarray, column: str, message: Any) -> None:
        for i in np.flatnonzero(rows)[:MAX_MESSAGES]:
            issues.append(Issue(message(int(i)), row=int(i), column=column))

    add(
        (m.pose_id < 1) | (m.pose_id > MAX_POSE_ID),
        "pose_id",
        lambda i: f"pose_id {int(m.pose_id[i])} is outside 1..{MAX_POSE_ID} (2**53 - 1)",
    )
    # (column, values, lowest, highest, unit)
    numeric = [("t", m.t, -MAX_TIME_S, MAX_TIME_S, "s")]
    coordinate = (-MAX_COORDINATE_MM, MAX_COORDINATE_MM, "mm")
    numeric += [(c, m.position[:, j], *coordinate) for j, c in enumerate(POSITION_COLUMNS)]
    numeric += [(c, m.quaternion[:, j], -2.0, 2.0, "") for j, c in enumerate(QUATERNION_COLUMNS)]
    numeric += [(c, m.readings[:, j], *coordinate) for j, c in enumerate(READING_COLUMNS)]
    if m.temperature is not None:
        numeric.append(("temperature", m.temperature, MIN_TEMPERATURE_C, MAX_TEMPERATURE_C, "degC"))
    for column, values, low, high, unit in numeric:
        finite = np.isfinite(values)
        # float(): a numpy scalar's repr is 'np.float64(nan)', not what a file would say.
        add(~finite, column, lambda i, v=values: f"{float(v[i])!r} is not finite")
        with np.errstate(invalid="ignore"):
            outside = finite & ((values < low) | (values > high))
        add(
            outside,
            column,
            lambda i, v=values, lo=low, hi=high, u=unit: (
                f"{float(v[i])!r} {u} is outside {lo:g}..{hi:g} {u}".replace("  ", " ")
            ),
        )
    with np.errstate(invalid="ignore"):
        norm = np.linalg.norm(m.quaternion, axis=1)
        add(
            np.abs(norm - 1.0) > QUATERNION_TOLERANCE,
            "qw",
            lambda i: (
                f"quaternion norm is {norm[i]:.6f}, not within {QUATERNION_TOLERANCE:g} "
                "of 1 (scalar first: qw, qx, qy, qz)"
            ),
        )
    add(
        np.array([s == "" for s in m.step.tolist()], dtype=bool),
        "step",
        lambda i: "the step is empty; name the procedure step",
    )
    known = np.array([c in CONSTRAINTS for c in m.constraint.tolist()], dtype=bool)
    add(
        ~known,
        "constraint",
        lambda i: f"{m.constraint[i]!r} is not one of {', '.join(CONSTRAINTS)}",
    )
    in_range = (m.leg >= 0) & (m.leg <= 6)
    add(~in_range, "leg", lambda i: f"leg {m.leg[i]} is outside 0..6 (0 = free pose)")
    free = np.array([c == "free" for c in m.constraint.tolist()], dtype=bool)
    add(
        known & in_range & ((m.leg == 0) != free),
        "constraint",
        lambda i: (
            f"constraint {m.constraint[i]!r} with leg {m.leg[i]}: free poses have leg 0, "
            "clamped ones leg 1..6"
        ),
    )
    return issues


def _duplicate_issues(pose_id: np.ndarray) -> list[Issue]:
    first: dict[int, int] = {}
    issues = []
    for i, p in enumerate(pose_id.tolist()):
        if p in first:
            issues.append(
                Issue(
                    f"pose_id {p} repeats index {first[p]}; pose ids must be unique",
                    row=i,
                    column="pose_id",
                )
            )
        else:
            first[p] = i
    return issues


@dataclass(frozen=True, eq=False)
class Measurements:
    """The measurement table: N recorded poses, in the order recorded.

    Equality (``==``) compares every array exactly, the extra columns and the header order;
    ``source`` is ignored. Arrays are coerced on construction (ints to int64, floats to float64,
    text to object arrays of str) and every row is checked against the rules of
    :class:`MeasurementRow`, except pose-id uniqueness, which :meth:`from_arrays`,
    :func:`read_measurements` and :func:`write_measurements` check (so :meth:`subset` can
    resample with repeats).
    """

    pose_id: np.ndarray  #: (N,) int
    t: np.ndarray  #: (N,) s since the session started
    step: np.ndarray  #: (N,) object (str), procedure step, e.g. "leg3-direction"
    leg: np.ndarray  #: (N,) int, 0 = free pose, 1..6 = clamped leg
    constraint: np.ndarray  #: (N,) object (str), one of CONSTRAINTS
    position: np.ndarray  #: (N, 3) mm, platform origin in the measurement frame
    quaternion: np.ndarray  #: (N, 4) scalar first, exactly as read (not renormalised)
    readings: np.ndarray  #: (N, 6) mm, encoder readings rho1..rho6
    temperature: np.ndarray | None  #: (N,) degC, None when the column is absent
    extra: dict[str, np.ndarray]  #: extra columns, in file order, (N,) object arrays of str
    columns: tuple[str, ...]  #: the header, in the order written back
    source: str | None = None  #: the file it was read from

    def __post_init__(self) -> None:
        n = len(np.asarray(self.pose_id).reshape(-1))
        fix = object.__setattr__  # frozen: coercion happens once, here
        fix(self, "pose_id", _int_array("pose_id", self.pose_id, n))
        fix(self, "t", _float_array("t", self.t, (n,)))
        fix(self, "step", _text_array("step", self.step, n))
        fix(self, "leg", _int_array("leg", self.leg, n))
        fix(self, "constraint", _text_array("constraint", self.constraint, n))
        fix(self, "position", _float_array("position", self.position, (n, 3)))
        fix(self, "quaternion", _float_array("quaternion", self.quaternion, (n, 4)))
        fix(self, "readings", _float_array("readings", self.readings, (n, 6)))
        if self.temperature is not None:
            fix(self, "temperature", _float_array("temperature", self.temperature, (n,)))
        extra = {str(k): _text_array(f"extra[{k!r}]", v, n) for k, v in self.extra.items()}
        fix(self, "extra", extra)
        fix(self, "columns", tuple(str(c) for c in self.columns))
        if self.source is not None:
            fix(self, "source", str(self.source))
        self._check_columns()
        _raise_issues(_value_issues(self), self.source)

    def _check_columns(self) -> None:
        cols = self.columns
        problems = []
        if len(set(cols)) != len(cols):
            problems.append("columns has duplicate names")
        missing = [c for c in REQUIRED_COLUMNS if c not in cols]
        if missing:
            problems.append(f"columns lacks {', '.join(missing)}")
        if ("temperature" in cols) != (self.temperature is not None):
            problems.append("'temperature' must be in columns exactly when temperature is given")
        others = [c for c in cols if c not in _KNOWN_COLUMNS]
        if set(others) != set(self.extra):
            problems.append(
                f"the extra columns {others} in columns differ from the extra keys "
                f"{list(self.extra)}"
            )
        if problems:
            raise ValueError("Measurements: " + "; ".join(problems))

    def __len__(self) -> int:
        return len(self.pose_id)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Measurements):
            return NotImplemented
        if self.columns != other.columns or len(self) != len(other):
            return False
        if (self.temperature is None) != (other.temperature is None):
            return False
        if set(self.extra) != set(other.extra):
            return False
        pairs = [
            (self.pose_id, other.pose_id),
            (self.t, other.t),
            (self.step, other.step),
            (self.leg, other.leg),
            (self.constraint, other.constraint),
            (self.position, other.position),
            (self.quaternion, other.quaternion),
            (self.readings, other.readings),
            *((self.extra[k], other.extra[k]) for k in self.extra),
        ]
        if self.temperature is not None:
            pairs.append((self.temperature, other.temperature))
        return all(np.array_equal(a, b) for a, b in pairs)

    @property
    def rotations(self) -> Rotation:
        """The platform orientations, N rotations (quaternions normalised by scipy)."""
        return Rotation.from_quat(self.quaternion, scalar_first=True)

    def subset(self, mask_or_index: Any) -> Measurements:
        """The rows picked by a boolean mask (N,), integer indices, a slice or one index.

        Every column, the extra columns, the header and ``source`` are carried along.
        """
        idx = np.atleast_1d(np.arange(len(self))[mask_or_index])
        return Measurements(
            pose_id=self.pose_id[idx],
            t=self.t[idx],
            step=self.step[idx],
            leg=self.leg[idx],
            constraint=self.constraint[idx],
            position=self.position[idx],
            quaternion=self.quaternion[idx],
            readings=self.readings[idx],
            temperature=None if self.temperature is None else self.temperature[idx],
            extra={k: v[idx] for k, v in self.extra.items()},
            columns=self.columns,
            source=self.source,
        )

    def select(self, leg: int, constraint: str) -> Measurements:
        """The poses with this clamped leg (1..6, 0 for free) and constraint (CONSTRAINTS)."""
        if constraint not in CONSTRAINTS:
            raise ValueError(f"unknown constraint {constraint!r}; use one of {CONSTRAINTS}")
        if not 0 <= int(leg) <= 6:
            raise ValueError(f"leg {leg} is outside 0..6 (0 = free pose)")
        return self.subset((self.leg == int(leg)) & (self.constraint == constraint))

    @classmethod
    def from_arrays(
        cls,
        position: Any,
        quaternion: Any,
        readings: Any,
        *,
        leg: Any = None,
        constraint: Any = None,
        step: Any = None,
        t: Any = None,
        pose_id: Any = None,
        temperature: Any = None,
        extra: Mapping[str, Any] | None = None,
    ) -> Measurements:
        """A table from arrays, e.g. simulated poses.

        position (N, 3) mm; quaternion (N, 4) scalar first, or a :class:`Rotation` of N
        rotations; readings (N, 6) mm. ``leg``, ``constraint``, ``step`` and ``temperature``
        may be scalars (applied to every row) or (N,). Defaults: free poses (leg 0, constraint
        'free'), pose_id 1..N, t = 0..N-1 s, step 'free' for free rows and ``leg{k}-{constraint}``
        for clamped ones, no temperature, no extra columns. The header is REQUIRED_COLUMNS, then
        'temperature' if given, then the extra keys. Text is stripped, as reading would.
        """
        position = np.asarray(position, dtype=float)
        if position.ndim != 2 or position.shape[1] != 3:
            raise ValueError(f"position must have shape (N, 3), got {position.shape}")
        n = position.shape[0]
        if isinstance(quaternion, Rotation):
            quaternion = np.atleast_2d(quaternion.as_quat(scalar_first=True))

        def full(name: str, value: Any, dtype: Any) -> np.ndarray:
            a = np.asarray(value, dtype=dtype)
            try:
                return np.broadcast_to(a, (n,)).copy()
            except ValueError:
                raise ValueError(
                    f"{name} must be a scalar or have shape ({n},), got {a.shape}"
                ) from None

        leg_a = np.zeros(n, dtype=np.int64) if leg is None else full("leg", leg, None)
        con_a = full("constraint", "free" if constraint is None else constraint, object)
        con_a = _object_array([str(c).strip() for c in con_a.tolist()])
        if step is None:
            step_a = _object_array(
                [
                    "free" if c == "free" else f"leg{int(k)}-{c}"
                    for k, c in zip(leg_a.tolist(), con_a.tolist(), strict=True)
                ]
            )
        else:
            step_a = _object_array([_to_text(s).strip() for s in full("step", step, object)])
        t_a = np.arange(n, dtype=float) if t is None else t
        id_a = np.arange(1, n + 1) if pose_id is None else pose_id
        temp_a = None if temperature is None else full("temperature", temperature, float)
        extra_a: dict[str, np.ndarray] = {}
        for name, values in (extra or {}).items():
            if not isinstance(name, str) or not name or name != name.strip():
                raise ValueError(f"extra column name {name!r} must be non-empty text, unpadded")
            if name in _KNOWN_COLUMNS:
                raise ValueError(f"extra column {name!r} clashes with a standard column")
            texts = full(f"extra[{name!r}]", values, object).tolist()
            extra_a[name] = _object_array([_to_text(v).strip() for v in texts])
        columns = (
            *REQUIRED_COLUMNS,
            *(("temperature",) if temp_a is not None else ()),
            *extra_a,
        )
        m = cls(
            pose_id=id_a,
            t=t_a,
            step=step_a,
            leg=leg_a,
            constraint=con_a,
            position=position,
            quaternion=quaternion,
            readings=readings,
            temperature=temp_a,
            extra=extra_a,
            columns=columns,
        )
        _raise_issues(_duplicate_issues(m.pose_id), None)
        return m


# --------------------------------------------------------------------------------------------
# Reading

#: Rows checked together: enough for numpy to pay off, few enough that a block's text (about
#: 50 bytes a field as Python strings) stays a few MB.
_BLOCK_ROWS = 4096


#: Bytes read at a time when looking for an undecodable byte.
_DECODE_BLOCK = 1 << 20


class _Slow(Exception):
    """A block breaks a rule: validate it row by row for the messages."""


def _undecodable(path: Path) -> MeasurementError:
    """The error for the file's first byte that is not UTF-8: its offset, line and column.

    Called only once decoding failed, so reading pays nothing for it: the file is read again
    in binary, a block at a time, through an incremental decoder."""
    decoder = codecs.getincrementaldecoder("utf-8")()
    offset = lines = 0  # bytes and line ends before the block
    tail = b""  # the current line's bytes before the block (its last MB at most)
    first_line: bytes | None = None
    with path.open("rb") as fh:
        while True:
            block = fh.read(_DECODE_BLOCK)
            buffered = len(decoder.getstate()[0])  # an incomplete character's first bytes
            try:
                decoder.decode(block, final=not block)
            except UnicodeDecodeError as exc:
                at = offset - buffered + exc.start  # in the file
                break
            if not block:  # pragma: no cover - the text reader found a bad byte
                return MeasurementError.single(path, None, None, "is not UTF-8 text")
            data = tail + block
            if first_line is None and b"\n" in data:
                first_line = data.split(b"\n", 1)[0]
            lines += block.count(b"\n")
            tail = data[data.rfind(b"\n") + 1 :][-_DECODE_BLOCK:]
            offset += len(block)
    data = tail + block
    i = at - (offset - len(tail))  # the bad byte in data
    line = lines + data.count(b"\n", 0, i) + 1
    if first_line is None:
        first_line = data.split(b"\n", 1)[0]
    column = None
    if line > 1:  # best effort: the header name of the field holding the byte
        before = data[data.rfind(b"\n", 0, i) + 1 : i].decode("utf-8", "replace")
        try:
            header = next(csv.reader([first_line.decode("utf-8", "replace").strip()]), [])
            index = max(len(next(csv.reader([before]), [])) - 1, 0)
        except csv.Error:
            header, index = [], 0
        if index < len(header):
            column = header[index].strip().lstrip("\ufeff")
    return MeasurementError.single(
        path,
        line,
        column,
        f"byte {at} (0x{data[i]:02x}) is not UTF-8 text; save the file as UTF-8 (e.g. 'CSV UTF-8')",
    )


def _header_issues(header: list[str], line: int) -> list[Issue]:
    issues = []
    seen: dict[str, int] = {}
    for k, name in enumerate(header):
        if not name:
            issues.append(
                Issue(
                    f"header column {k + 1} has no name; name it or delete the column "
                    "(a trailing comma?)",
                    line=line,
                )
            )
        elif name in seen:
            issues.append(
                Issue(
                    f"column name '{name}' appears twice (columns {seen[name] + 1} and {k + 1}); "
                    "rename or delete one",
                    line=line,
                    column=name,
                )
            )
        else:
            seen[name] = k
    missing = [c for c in REQUIRED_COLUMNS if c not in seen]
    if missing:
        lower = {name.lower(): name for name in seen}
        named = [
            f"'{c}'" + (f" (found '{lower[c]}': names are lower case)" if c in lower else "")
            for c in missing
        ]
        issues.append(
            Issue(
                f"required column(s) {', '.join(named)} missing from the header; the header "
                f"must name {','.join(REQUIRED_COLUMNS)} (temperature and extra columns "
                "optional)",
                line=line,
                column=missing[0],
            )
        )
    return issues


def _count_issue(fields: list[str], header: list[str], line: int) -> Issue:
    n, ncol = len(fields), len(header)
    if n < ncol:
        return Issue(
            f"{n} fields but the header has {ncol} columns: '{header[n]}' and after are missing; "
            "complete the row or remove it",
            line=line,
            column=header[n],
        )
    trailing = " (a trailing comma?)" if not any(fields[ncol:]) else ""
    return Issue(
        f"{n} fields but the header has {ncol} columns: {n - ncol} field(s) after the last "
        f"column '{header[-1]}'{trailing}; remove them, or name them in the header",
        line=line,
    )


@dataclass
class _Block:
    """Consecutive valid rows of the file, typed (units as in :class:`Measurements`)."""

    line: np.ndarray  #: (k,) the line each row starts on
    pose_id: np.ndarray
    t: np.ndarray
    step: list[str]
    leg: np.ndarray
    constraint: list[str]
    position: np.ndarray
    quaternion: np.ndarray
    readings: np.ndarray
    temperature: np.ndarray | None
    extra: list[list[str]]  #: per extra column, in header order


class _TableReader:
    """Turns the file's data rows into typed arrays a block at a time.

    A block that keeps every rule is converted with numpy (the common case, and what keeps a
    200 MB file fast); a block that breaks one is validated row by row with
    :class:`MeasurementRow`, whose messages the error reports. Once a row is bad the values
    are no longer kept (the read will fail), only the ids and lines that duplicates are checked
    against."""

    def __init__(self, header: list[str], path: Path):
        self.header = header
        self.path = path
        self.at = {c: k for k, c in enumerate(header)}
        self.fields = [c for c in header if c in _KNOWN_COLUMNS]
        self.extra_names = [c for c in header if c not in _KNOWN_COLUMNS]
        self.has_temperature = "temperature" in self.at
        self.blocks: list[_Block] = []
        self.ids: list[np.ndarray] = []
        self.lines: list[np.ndarray] = []
        self.issues: list[Issue] = []  # the first MAX_MESSAGES row problems
        self.problems = 0  # all of them
        self.rows = 0
        self.texts: dict[str, str] = {}  # one str object per distinct step/constraint

    def flush(self, rows: list[tuple[int, list[str]]]) -> None:
        """Take a block of data rows: (line, fields as read, not stripped)."""
        if not rows:
            return
        self.rows += len(rows)
        try:
            block = self._fast(rows)
        except _Slow:
            block = self._slow(rows)
        self.ids.append(block.pose_id)
        self.lines.append(block.line)
        if self.problems:
            self.blocks.clear()
        else:
            self.blocks.append(block)

    # -- the fast path: a block with no problem, checked by columns --------------------------

    def _column(self, cols: list[tuple[str, ...]], name: str) -> tuple[str, ...]:
        col = cols[self.at[name]]
        joined = "".join(col)
        # As _parse_number/_parse_integer: no empty field, ASCII only, no digit separators
        # (float() and int() would take '1_000' and non-ASCII digits).
        if "" in col or "_" in joined or not joined.isascii():
            raise _Slow
        return col

    def _floats(self, cols: list[tuple[str, ...]], names: Sequence[str]) -> np.ndarray:
        try:
            out = np.array([list(map(float, self._column(cols, c))) for c in names]).T
        except ValueError:
            raise _Slow from None
        return out

    def _ints(self, cols: list[tuple[str, ...]], name: str, low: int, high: int) -> np.ndarray:
        try:
            values = np.array(list(map(int, self._column(cols, name))), dtype=np.int64)
        except (ValueError, OverflowError):  # '3.0' is valid: the slow path reads it
            raise _Slow from None
        if not np.all((values >= low) & (values <= high)):
            raise _Slow
        return values

    def _within(self, values: np.ndarray, low: float, high: float) -> np.ndarray:
        if not np.all((values >= low) & (values <= high)):  # False for NaN too
            raise _Slow
        return values

    def _texts(self, col: Sequence[str]) -> list[str]:
        """Stripped text, one str object per distinct value (a step name is shared by many
        rows: memory)."""
        col = list(map(str.strip, col))
        cache = self.texts
        if len(cache) > 10_000:  # steps are a few dozen names; do not hoard unique ones
            return col
        return [cache.setdefault(v, v) for v in col]

    def _fast(self, rows: list[tuple[int, list[str]]]) -> _Block:
        ncol = len(self.header)
        if any(len(fields) != ncol for _, fields in rows):
            raise _Slow
        cols = list(zip(*(fields for _, fields in rows), strict=True))
        pose_id = self._ints(cols, "pose_id", 1, MAX_POSE_ID)
        leg = self._ints(cols, "leg", 0, 6)
        t = self._within(self._floats(cols, ["t"])[:, 0], -MAX_TIME_S, MAX_TIME_S)
        position = self._floats(cols, POSITION_COLUMNS)
        readings = self._floats(cols, READING_COLUMNS)
        self._within(position, -MAX_COORDINATE_MM, MAX_COORDINATE_MM)
        self._within(readings, -MAX_COORDINATE_MM, MAX_COORDINATE_MM)
        quaternion = self._floats(cols, QUATERNION_COLUMNS)
        with np.errstate(over="ignore", invalid="ignore"):
            norm = np.sqrt(np.sum(quaternion * quaternion, axis=1))
        # A hair inside the tolerance: a row at its very edge goes to MeasurementRow, whose
        # sum (in another order) has the last word.
        edge = QUATERNION_TOLERANCE * (1 - 1e-9)
        self._within(norm, 1.0 - edge, 1.0 + edge)
        temperature = None
        if self.has_temperature:
            temperature = self._floats(cols, ["temperature"])[:, 0]
            self._within(temperature, MIN_TEMPERATURE_C, MAX_TEMPERATURE_C)
        # Text may hold any character ('leg1_direction', 'Bein 1'): stripped, never empty.
        step = self._texts(cols[self.at["step"]])
        constraint = self._texts(cols[self.at["constraint"]])
        if "" in step or not set(constraint) <= set(CONSTRAINTS):
            raise _Slow
        free = np.array([c == "free" for c in constraint], dtype=bool)
        if np.any(free != (leg == 0)):
            raise _Slow
        return _Block(
            line=np.array([line for line, _ in rows], dtype=np.int64),
            pose_id=pose_id,
            t=t,
            step=step,
            leg=leg,
            constraint=constraint,
            position=position,
            quaternion=quaternion,
            readings=readings,
            temperature=temperature,
            extra=[list(map(str.strip, cols[self.at[c]])) for c in self.extra_names],
        )

    # -- the slow path: row by row, every problem named ----------------------------------------

    def _issue(self, issue: Issue) -> None:
        self.problems += 1
        if len(self.issues) < MAX_MESSAGES:
            self.issues.append(issue)

    def _slow(self, rows: list[tuple[int, list[str]]]) -> _Block:
        header, order = self.header, self.at
        valid: list[tuple[int, MeasurementRow, list[str]]] = []
        for line, fields in rows:
            values = [f.strip() for f in fields]
            if len(values) != len(header):
                self._issue(_count_issue(values, header, line))
                continue
            by_name = dict(zip(header, values, strict=True))
            try:
                row = MeasurementRow.model_validate({c: by_name[c] for c in self.fields})
            except ValidationError as exc:
                found = _row_issues(exc, line, by_name)
                for issue in sorted(found, key=lambda i: order.get(i.column or "", len(order))):
                    self._issue(issue)
                continue
            valid.append((line, row, [by_name[c] for c in self.extra_names]))
        rs = [r for _, r, _ in valid]
        return _Block(
            line=np.array([line for line, _, _ in valid], dtype=np.int64),
            pose_id=np.array([r.pose_id for r in rs], dtype=np.int64),
            t=np.array([r.t for r in rs], dtype=float),
            step=self._texts([r.step for r in rs]),
            leg=np.array([r.leg for r in rs], dtype=np.int64),
            constraint=self._texts([r.constraint for r in rs]),
            position=np.array([[r.x, r.y, r.z] for r in rs], dtype=float).reshape(-1, 3),
            quaternion=np.array([[r.qw, r.qx, r.qy, r.qz] for r in rs], dtype=float).reshape(-1, 4),
            readings=np.array(
                [[r.rho1, r.rho2, r.rho3, r.rho4, r.rho5, r.rho6] for r in rs], dtype=float
            ).reshape(-1, 6),
            temperature=(
                np.array([r.temperature for r in rs], dtype=float) if self.has_temperature else None
            ),
            extra=[[e[k] for _, _, e in valid] for k in range(len(self.extra_names))],
        )

    # -- the table ------------------------------------------------------------------------------

    def finish(self) -> Measurements:
        ids = np.concatenate(self.ids) if self.ids else np.zeros(0, np.int64)
        lines = np.concatenate(self.lines) if self.lines else np.zeros(0, np.int64)
        duplicates, repeated = _repeated_ids(ids, lines)
        if self.problems or repeated:
            # Both lists are in line order and hold the first MAX_MESSAGES of their kind, so
            # the first MAX_MESSAGES of the merge are the file's first problems.
            issues = sorted(self.issues + duplicates, key=lambda i: i.line or 0)[:MAX_MESSAGES]
            total = self.problems + repeated
            raise MeasurementError(issues, self.path, omitted=total - len(issues))
        b = self.blocks

        def cat(name: str) -> np.ndarray:
            return np.concatenate([getattr(x, name) for x in b])

        def texts(values: list[str]) -> np.ndarray:
            return _object_array(values)

        return Measurements(
            pose_id=ids,
            t=cat("t"),
            step=texts([s for x in b for s in x.step]),
            leg=cat("leg"),
            constraint=texts([s for x in b for s in x.constraint]),
            position=cat("position"),
            quaternion=cat("quaternion"),
            readings=cat("readings"),
            temperature=cat("temperature") if self.has_temperature else None,
            extra={
                c: texts([s for x in b for s in x.extra[k]]) for k, c in enumerate(self.extra_names)
            },
            columns=tuple(self.header),
            source=str(self.path),
        )


def _repeated_ids(ids: np.ndarray, lines: np.ndarray) -> tuple[list[Issue], int]:
    """The rows whose pose_id an earlier row already has (the first MAX_MESSAGES, in line
    order), and how many there are; ``ids`` and ``lines`` in file order."""
    if len(ids) < 2:
        return [], 0
    _, first, group = np.unique(ids, return_index=True, return_inverse=True)
    group = group.reshape(-1)
    repeats = np.flatnonzero(first[group] != np.arange(len(ids)))
    issues = [
        Issue(
            f"pose_id {int(ids[i])} was already used on line {int(lines[first[group[i]]])}; "
            "pose ids must be unique: renumber or remove the row",
            line=int(lines[i]),
            column="pose_id",
        )
        for i in repeats[:MAX_MESSAGES]
    ]
    return issues, len(repeats)


def read_measurements(path: str | Path) -> Measurements:
    """Read and validate measurements.csv (docs/formats.md).

    Raises :class:`MeasurementError` listing every bad row (up to :data:`MAX_MESSAGES`), each
    with file, line (header = line 1) and column; also for a missing, unreadable, non-UTF-8,
    empty or too large (:data:`hexcal.safe_read.KINDS`) file. Floats keep the exact value
    written; extra columns keep their text. The file is streamed: memory stays about its size.
    """
    path = Path(path)

    def error(message: str) -> MeasurementError:
        return MeasurementError.single(path, None, None, message.removeprefix(f"{path}: "))

    with open_binary(path, "measurements", error) as fh:
        # utf-8-sig drops a leading byte-order mark (spreadsheet exports); newline="" keeps
        # line ends as they are, as the csv module wants.
        stream = io.TextIOWrapper(fh, encoding="utf-8-sig", newline="")
        try:
            return _read_table(stream, path)
        except UnicodeDecodeError:
            raise _undecodable(path) from None
        except OSError as exc:
            raise error(f"cannot be read ({exc.strerror or exc})") from None


def _read_table(stream: io.TextIOWrapper, path: Path) -> Measurements:
    reader = csv.reader(stream)
    table: _TableReader | None = None
    pending: list[tuple[int, list[str]]] = []
    header_line = 1
    start = 1
    try:
        for fields in reader:
            line, start = start, reader.line_num + 1
            # Blank lines and the all-comma rows spreadsheets append hold no data at all.
            # (Fields are stripped where they are used: the fast path leaves numbers as they
            # are, since float() and int() ignore the same spaces str.strip() removes.)
            if not fields or (not fields[0].strip() and not "".join(fields).strip()):
                continue
            if table is not None:
                pending.append((line, fields))
                if len(pending) >= _BLOCK_ROWS:
                    table.flush(pending)
                    pending = []
                continue
            header_line = line
            header = [f.strip() for f in fields]
            _raise_issues(_header_issues(header, line), path)
            table = _TableReader(header, path)
    except csv.Error as exc:
        raise MeasurementError.single(
            path, reader.line_num, None, f"not valid CSV ({exc}); fix the line or remove it"
        ) from None
    if table is None:
        raise MeasurementError.single(
            path, 1, None, f"the file is empty; it needs the header {','.join(REQUIRED_COLUMNS)}"
        )
    table.flush(pending)
    if table.rows == 0:
        raise MeasurementError.single(
            path, header_line + 1, None, "no data rows after the header; record at least one pose"
        )
    return table.finish()


# --------------------------------------------------------------------------------------------
# Writing


def _floats(values: np.ndarray) -> list[str]:
    # repr is the shortest text that parses back to the same double: lossless and compact.
    return [repr(v) for v in values.astype(float).tolist()]


def _column_texts(m: Measurements, name: str) -> list[str]:
    if name in ("pose_id", "leg"):
        return [str(v) for v in getattr(m, name).tolist()]
    if name in ("step", "constraint"):
        return list(getattr(m, name).tolist())
    if name in ("t",):
        return _floats(m.t)
    if name in POSITION_COLUMNS:
        return _floats(m.position[:, POSITION_COLUMNS.index(name)])
    if name in QUATERNION_COLUMNS:
        return _floats(m.quaternion[:, QUATERNION_COLUMNS.index(name)])
    if name in READING_COLUMNS:
        return _floats(m.readings[:, READING_COLUMNS.index(name)])
    if name == "temperature":
        assert m.temperature is not None  # guaranteed by Measurements._check_columns
        return _floats(m.temperature)
    return list(m.extra[name].tolist())


def measurements_to_csv_text(m: Measurements) -> str:
    """The CSV text of ``m``: header ``m.columns``, one row per pose, '\\n' line ends."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(m.columns)
    writer.writerows(zip(*(_column_texts(m, c) for c in m.columns), strict=True))
    return buf.getvalue()


def write_measurements(m: Measurements, path: str | Path) -> None:
    """Write ``m`` to ``path`` atomically (temp file in the same folder, fsync, rename).

    Refuses (ValueError) what could not be read back: no rows, or a repeated pose_id.
    """
    if len(m) == 0:
        raise ValueError(f"{path}: no poses to write; a measurement table needs at least one row")
    _raise_issues(_duplicate_issues(m.pose_id), path)
    write_text_atomic(path, measurements_to_csv_text(m))
