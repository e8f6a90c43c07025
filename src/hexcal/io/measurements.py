"""The measurement table (``measurements.csv`` of docs/formats.md): held, checked, written.

One row per recorded pose: its id, time (s), procedure step, the clamped leg (1..6, 0 for a free
pose) and the constraint applied, the platform pose from the tracker (position mm, unit
quaternion scalar first) and the six encoder readings (mm), optionally the structure temperature
(degC). Extra columns are carried through untouched.

Reading (:func:`~hexcal.io.measurements_csv.read_measurements`) and the row rules
(:class:`~hexcal.io.measurements_csv.MeasurementRow`) are in :mod:`hexcal.io.measurements_csv`,
which imports this module (never the other way round): the file is streamed row by row into
typed arrays, and *all* bad rows are reported in one :class:`MeasurementError` naming the
file, the line and the column. Values are held to the ranges of :mod:`hexcal.io.safe_read`.
Writing is lossless:
floats are written with ``repr`` (shortest round-trip form), the column order is kept, and
``read_measurements(p)`` after ``write_measurements(m, p)`` equals ``m`` exactly.
"""

from __future__ import annotations

import csv
import io
import math
import operator
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.errors import InputError
from hexcal.io.fileio import write_text_atomic
from hexcal.io.safe_read import (
    MAX_COORDINATE_MM,
    MAX_POSE_ID,
    MAX_TEMPERATURE_C,
    MAX_TIME_S,
    MIN_TEMPERATURE_C,
)
from hexcal.vocabulary import Constraint

#: Type I, Type II, Type III, and no constraint: the values of :class:`Constraint`, as the
#: table writes them.
CONSTRAINTS = tuple(c.value for c in Constraint)
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


class MeasurementError(InputError):
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
# The table in memory


def _object_array(values: Sequence[Any]) -> np.ndarray:
    # Filling a preallocated object array keeps it 1-D whatever the elements are.
    out = np.empty(len(values), dtype=object)
    out[:] = list(values)
    return out


def _to_text(value: Any) -> str:
    """Text of one extra/step value: strings as they are, floats in round-trip form."""
    if isinstance(value, str):
        return str(value)  # a Constraint (a str) as its value
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
        np.asarray(m.step == "", dtype=bool),
        "step",
        lambda i: "the step is empty; name the procedure step",
    )
    # Whole-column comparisons: no Python loop over the rows.
    known = np.zeros(len(m), dtype=bool)
    for c in CONSTRAINTS:
        known |= np.asarray(m.constraint == c, dtype=bool)
    add(
        ~known,
        "constraint",
        lambda i: f"{m.constraint[i]!r} is not one of {', '.join(CONSTRAINTS)}",
    )
    in_range = (m.leg >= 0) & (m.leg <= 6)
    add(~in_range, "leg", lambda i: f"leg {m.leg[i]} is outside 0..6 (0 = free pose)")
    free_ = Constraint.FREE.value  # once, as plain text: the fastest comparison
    free = np.asarray(m.constraint == free_, dtype=bool)
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
    constraint: np.ndarray  #: (N,) object (str), one of CONSTRAINTS (a Constraint's value)
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
        same = all(np.array_equal(a, b) for a, b in pairs)
        if self.temperature is not None or other.temperature is not None:
            same = same and (
                self.temperature is not None
                and other.temperature is not None
                and np.array_equal(self.temperature, other.temperature)
            )
        return same

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

    def select(self, leg: int, constraint: Constraint | str) -> Measurements:
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
        con_a = full("constraint", Constraint.FREE if constraint is None else constraint, object)
        con_a = _object_array([str(c).strip() for c in con_a.tolist()])
        if step is None:
            free = Constraint.FREE.value
            step_a = _object_array(
                [
                    "free" if c == free else f"leg{int(k)}-{c}"
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
    return "".join(measurements_csv_pieces(m))


def measurements_csv_pieces(m: Measurements, rows: int = 8192) -> Iterator[str]:
    """The CSV text of ``m`` (as :func:`measurements_to_csv_text`) ``rows`` rows at a time, so
    that a table of millions of poses is written without its whole text in memory (a row's
    fields as Python strings take about ten times the row's bytes)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(m.columns)
    for a in range(0, len(m), rows):
        part = m.subset(slice(a, a + rows)) if len(m) > rows else m
        writer.writerows(zip(*(_column_texts(part, c) for c in m.columns), strict=True))
        yield buf.getvalue()
        buf.seek(0)
        buf.truncate()
    if not len(m):
        yield buf.getvalue()


def write_measurements(m: Measurements, path: str | Path) -> None:
    """Write ``m`` to ``path`` atomically (temp file in the same folder, fsync, rename).

    Refuses (ValueError) what could not be read back: no rows, or a repeated pose_id.
    """
    if len(m) == 0:
        raise ValueError(f"{path}: no poses to write; a measurement table needs at least one row")
    _raise_issues(_duplicate_issues(m.pose_id), path)
    write_text_atomic(path, measurements_to_csv_text(m))
