"""The measurement table (``measurements.csv`` of docs/formats.md): read, validate, write.

One row per recorded pose: its id, time (s), procedure step, the clamped leg (1..6, 0 for a free
pose) and the constraint applied, the platform pose from the tracker (position mm, unit
quaternion scalar first) and the six encoder readings (mm), optionally the structure temperature
(degC). Extra columns are carried through untouched.

Reading validates every row with :class:`MeasurementRow` (pydantic v2) and reports *all* bad rows
in one :class:`MeasurementError` naming the file, the line and the column. Writing is lossless:
floats are written with ``repr`` (shortest round-trip form), the column order is kept, and
``read_measurements(p)`` after ``write_measurements(m, p)`` equals ``m`` exactly.
"""

from __future__ import annotations

import codecs
import csv
import io
import math
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


Number = Annotated[float, BeforeValidator(_parse_number)]
Integer = Annotated[int, BeforeValidator(_parse_integer)]
Text = Annotated[str, BeforeValidator(_parse_text)]
Leg = Annotated[int, BeforeValidator(_parse_integer), AfterValidator(_check_leg)]
Constraint = Annotated[str, BeforeValidator(_parse_text), AfterValidator(_check_constraint)]
# Not ``Number | None``: a union would report a bad value once per member, with a mangled location.
OptionalNumber = Annotated[
    float | None, BeforeValidator(lambda v: None if v is None else _parse_number(v))
]


class MeasurementRow(BaseModel):
    """One row of measurements.csv, validated.

    Units: ``t`` s; ``x, y, z`` mm (platform origin in the measurement frame); ``qw..qz`` unit
    quaternion, scalar first (norm within :data:`QUATERNION_TOLERANCE` of 1); ``rho1..rho6`` mm;
    ``temperature`` degC or None when the file has no such column. Fields accept the raw CSV
    strings; whitespace around them is ignored.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    pose_id: Integer
    t: Number
    step: Text
    leg: Leg
    constraint: Constraint
    x: Number
    y: Number
    z: Number
    qw: Number
    qx: Number
    qy: Number
    qz: Number
    rho1: Number
    rho2: Number
    rho3: Number
    rho4: Number
    rho5: Number
    rho6: Number
    temperature: OptionalNumber = None

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
    return _object_array([_to_text(v) for v in a.tolist()])


def _float_array(name: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    a = np.asarray(value, dtype=float)
    if a.size == 0 and len(shape) == 2:
        a = a.reshape(0, shape[1])
    if a.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {a.shape}")
    return a


def _int_array(name: str, value: Any, n: int) -> np.ndarray:
    a = np.asarray(value)
    if a.size == 0:
        a = a.reshape(0).astype(np.int64)
    if a.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {a.shape}")
    if a.dtype.kind in "iu":
        return a.astype(np.int64)
    try:
        f = a.astype(float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must hold integers") from None
    if not (np.all(np.isfinite(f)) and np.all(f == np.round(f))):
        raise ValueError(f"{name} must hold integers")
    return f.astype(np.int64)


def _value_issues(m: Measurements) -> list[Issue]:
    """The row rules of :class:`MeasurementRow`, vectorised, for data not read from a file."""
    issues: list[Issue] = []

    def add(rows: np.ndarray, column: str, message: Any) -> None:
        for i in np.flatnonzero(rows)[:MAX_MESSAGES]:
            issues.append(Issue(message(int(i)), row=int(i), column=column))

    numeric = [("t", m.t)]
    numeric += [(c, m.position[:, j]) for j, c in enumerate(POSITION_COLUMNS)]
    numeric += [(c, m.quaternion[:, j]) for j, c in enumerate(QUATERNION_COLUMNS)]
    numeric += [(c, m.readings[:, j]) for j, c in enumerate(READING_COLUMNS)]
    if m.temperature is not None:
        numeric.append(("temperature", m.temperature))
    for column, values in numeric:
        add(~np.isfinite(values), column, lambda i, v=values: f"{v[i]!r} is not finite")
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


def _decode(raw: bytes, path: Path) -> str:
    """UTF-8 text of the file; a leading byte-order mark (spreadsheet exports) is dropped."""
    skip = len(codecs.BOM_UTF8) if raw.startswith(codecs.BOM_UTF8) else 0
    try:
        return raw[skip:].decode("utf-8")
    except UnicodeDecodeError as exc:
        at = exc.start + skip
        line = raw.count(b"\n", 0, at) + 1
        raise MeasurementError.single(
            path,
            line,
            _column_at(raw, at, line),
            f"byte 0x{raw[at]:02x} is not UTF-8; save the file as UTF-8 (e.g. 'CSV UTF-8')",
        ) from None


def _column_at(raw: bytes, at: int, line: int) -> str | None:
    """Best effort: the header name of the field holding byte ``at``, None on the header."""
    if line == 1:
        return None
    try:
        header_bytes = raw.split(b"\n", 1)[0]
        header = next(csv.reader([header_bytes.decode("utf-8", "replace").strip()]))
        start = raw.rfind(b"\n", 0, at) + 1
        before = raw[start:at].decode("utf-8", "replace")
        index = max(len(next(csv.reader([before]), [])) - 1, 0)
        return header[index].strip().lstrip("\ufeff") if index < len(header) else None
    except (csv.Error, StopIteration, IndexError):
        return None


def _csv_rows(text: str, path: Path) -> list[tuple[int, list[str]]]:
    """Non-blank CSV records with the 1-based line each starts on, fields stripped."""
    reader = csv.reader(io.StringIO(text, newline=""))
    rows = []
    start = 1
    try:
        for fields in reader:
            line, start = start, reader.line_num + 1
            fields = [f.strip() for f in fields]
            # Blank lines and the all-comma rows spreadsheets append hold no data at all.
            if any(fields):
                rows.append((line, fields))
    except csv.Error as exc:
        raise MeasurementError.single(
            path, reader.line_num, None, f"not valid CSV ({exc}); fix the line or remove it"
        ) from None
    return rows


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


def read_measurements(path: str | Path) -> Measurements:
    """Read and validate measurements.csv (docs/formats.md).

    Raises :class:`MeasurementError` listing every bad row (up to :data:`MAX_MESSAGES`), each
    with file, line (header = line 1) and column; also for a missing, unreadable, non-UTF-8 or
    empty file. Floats keep the exact value written; extra columns keep their text.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise MeasurementError.single(
            path, None, None, "no such file; check the path to the measurement table"
        ) from None
    except IsADirectoryError:
        raise MeasurementError.single(
            path, None, None, "is a directory; pass the measurement table (a .csv file)"
        ) from None
    except OSError as exc:
        raise MeasurementError.single(
            path, None, None, f"cannot be read ({exc.strerror}); check its permissions"
        ) from None
    rows = _csv_rows(_decode(raw, path), path)
    if not rows:
        raise MeasurementError.single(
            path, 1, None, f"the file is empty; it needs the header {','.join(REQUIRED_COLUMNS)}"
        )
    header_line, header = rows[0]
    _raise_issues(_header_issues(header, header_line), path)
    data = rows[1:]
    if not data:
        raise MeasurementError.single(
            path, header_line + 1, None, "no data rows after the header; record at least one pose"
        )

    fields = [c for c in header if c in _KNOWN_COLUMNS]
    extra_names = [c for c in header if c not in _KNOWN_COLUMNS]
    order = {c: k for k, c in enumerate(header)}
    valid: list[tuple[MeasurementRow, list[str]]] = []
    issues: list[Issue] = []
    first_line: dict[int, int] = {}
    for line, values in data:
        if len(values) != len(header):
            issues.append(_count_issue(values, header, line))
            continue
        by_name = dict(zip(header, values, strict=True))
        try:
            row = MeasurementRow.model_validate({c: by_name[c] for c in fields})
        except ValidationError as exc:
            found = _row_issues(exc, line, by_name)
            issues.extend(sorted(found, key=lambda i: order.get(i.column or "", len(order))))
            continue
        if row.pose_id in first_line:
            issues.append(
                Issue(
                    f"pose_id {row.pose_id} was already used on line {first_line[row.pose_id]}; "
                    "pose ids must be unique: renumber or remove the row",
                    line=line,
                    column="pose_id",
                )
            )
            continue
        first_line[row.pose_id] = line
        valid.append((row, [by_name[c] for c in extra_names]))
    _raise_issues(issues, path)

    rows_ = [r for r, _ in valid]
    return Measurements(
        pose_id=np.array([r.pose_id for r in rows_], dtype=np.int64),
        t=np.array([r.t for r in rows_], dtype=float),
        step=_object_array([r.step for r in rows_]),
        leg=np.array([r.leg for r in rows_], dtype=np.int64),
        constraint=_object_array([r.constraint for r in rows_]),
        position=np.array([[r.x, r.y, r.z] for r in rows_], dtype=float),
        quaternion=np.array([[r.qw, r.qx, r.qy, r.qz] for r in rows_], dtype=float),
        readings=np.array(
            [[r.rho1, r.rho2, r.rho3, r.rho4, r.rho5, r.rho6] for r in rows_], dtype=float
        ),
        temperature=(
            np.array([r.temperature for r in rows_], dtype=float)
            if "temperature" in header
            else None
        ),
        extra={c: _object_array([e[k] for _, e in valid]) for k, c in enumerate(extra_names)},
        columns=tuple(header),
        source=str(path),
    )


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
