"""Import a lab's own log: its columns, units and conventions mapped onto the measurement table.

A small mapping file (TOML) says which column holds what; hexcal converts and checks every row
and writes the interchange table (measurements.csv). Example, a motion-capture log with motor
positions in revolutions and quaternions scalar last (examples/jugglebot/map.toml)::

    [pose]
    position = ["position_x", "position_y", "position_z"]
    position_unit = "mm"                    # mm, m, cm or um
    quaternion = ["orientation_x", "orientation_y", "orientation_z", "orientation_w"]
    quaternion_order = "xyzw"               # the order of the columns above: wxyz or xyzw
    # or: euler = ["rx", "ry", "rz"], euler_sequence = "xyz" (scipy: lower case extrinsic,
    #     upper case intrinsic), euler_unit = "deg" or "rad"

    [readings]
    columns = ["leg_length_1", "leg_length_2", "leg_length_3",
               "leg_length_4", "leg_length_5", "leg_length_6"]
    unit = "rev"                            # mm, um, m, counts or rev
    mm_per_unit = [75.692, 71.1967, 72.3416, 70.8009, 70.6211, 71.2628]  # counts, rev: per leg
    zero = [0, 0, 0, 0, 0, 0]               # optional: subtracted first, in the log's unit

    [columns]                               # optional, each a column name
    time = "t"                              # s (time_unit = "ms" for milliseconds)
    temperature = "temp_c"                  # degC
    step = "phase"
    leg = "clamped_leg"                     # 0 for a free pose, else 1..6
    constraint = "clamp"                    # direction, direction+length, length or free
    pose_id = "id"

Rows missing a column, or holding a value that is not a finite number, are refused with the
file, line and column named. Without a time column, ``t`` is the row index (s); without step,
leg and constraint every pose is a free pose, in the log's order.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator
from scipy.spatial.transform import Rotation

from hexcal.errors import InputError
from hexcal.io.csv_dialect import grouping_hint, table_rows, table_text, to_point
from hexcal.io.measurements import CONSTRAINTS, Measurements
from hexcal.io.safe_read import MB, FileKind, read_bytes, read_toml
from hexcal.io.validation import format_validation_error
from hexcal.vocabulary import Constraint

#: The files this module reads (sizes: a mapping is a few lines; a log is read whole).
MAP_KIND = FileKind("log mapping file", 1 * MB, "no such mapping file; pass it with --map")
LOG_KIND = FileKind("lab log", 256 * MB, "no such log file")

POSITION_UNITS = {"mm": 1.0, "m": 1000.0, "cm": 10.0, "um": 1e-3}
LINEAR_UNITS = {"mm": 1.0, "um": 1e-3, "m": 1000.0}
SCALED_UNITS = ("counts", "rev")


class LogImportError(InputError):
    """The log or its mapping cannot be read; the message names the file, line and column."""


class PoseMap(BaseModel):
    model_config = ConfigDict(extra="forbid")
    position: list[str] = Field(min_length=3, max_length=3)
    position_unit: str = "mm"
    quaternion: list[str] | None = Field(None, min_length=4, max_length=4)
    quaternion_order: str = "wxyz"
    euler: list[str] | None = Field(None, min_length=3, max_length=3)
    euler_sequence: str = "xyz"
    euler_unit: str = "deg"

    @field_validator("position_unit")
    @classmethod
    def _unit(cls, u: str) -> str:
        if u not in POSITION_UNITS:
            raise ValueError(f"position_unit {u!r}: use one of {', '.join(POSITION_UNITS)}")
        return u

    @field_validator("quaternion_order")
    @classmethod
    def _order(cls, o: str) -> str:
        if o not in ("wxyz", "xyzw"):
            raise ValueError(f"quaternion_order {o!r}: use 'wxyz' (scalar first) or 'xyzw'")
        return o

    @field_validator("euler_unit")
    @classmethod
    def _angle(cls, u: str) -> str:
        if u not in ("deg", "rad"):
            raise ValueError(f"euler_unit {u!r}: use 'deg' or 'rad'")
        return u


class ReadingsMap(BaseModel):
    model_config = ConfigDict(extra="forbid")
    columns: list[str] = Field(min_length=6, max_length=6)
    unit: str = "mm"
    mm_per_unit: list[float] | None = Field(None, min_length=6, max_length=6)
    zero: list[float] = Field(default_factory=lambda: [0.0] * 6, min_length=6, max_length=6)

    @field_validator("unit")
    @classmethod
    def _unit(cls, u: str) -> str:
        if u not in (*LINEAR_UNITS, *SCALED_UNITS):
            raise ValueError(f"unit {u!r}: use one of {', '.join((*LINEAR_UNITS, *SCALED_UNITS))}")
        return u

    @field_validator("mm_per_unit", "zero")
    @classmethod
    def _finite(cls, v: list[float] | None) -> list[float] | None:
        if v is not None and not np.all(np.isfinite(v)):
            raise ValueError("every value must be a finite number")
        return v


class ColumnsMap(BaseModel):
    model_config = ConfigDict(extra="forbid")
    time: str | None = None
    time_unit: str = "s"
    temperature: str | None = None
    step: str | None = None
    leg: str | None = None
    constraint: str | None = None
    pose_id: str | None = None


class LogMap(BaseModel):
    """The mapping file (see the module docstring)."""

    model_config = ConfigDict(extra="forbid")
    pose: PoseMap
    readings: ReadingsMap
    columns: ColumnsMap = ColumnsMap()

    def numeric_columns(self) -> list[str]:
        """The log's columns that hold numbers (where a decimal comma is read as a point)."""
        p, c = self.pose, self.columns
        names = [*p.position, *(p.quaternion or p.euler or []), *self.readings.columns]
        return names + [n for n in (c.time, c.temperature, c.leg, c.pose_id) if n]

    def check(self, where: str) -> None:
        p, r = self.pose, self.readings
        if (p.quaternion is None) == (p.euler is None):
            raise LogImportError(f"{where}: [pose] needs either quaternion or euler, not both")
        if r.unit in SCALED_UNITS and r.mm_per_unit is None:
            raise LogImportError(
                f"{where}: [readings] unit {r.unit!r} needs mm_per_unit, six values (one per leg)"
            )
        if self.columns.time_unit not in ("s", "ms"):
            raise LogImportError(f"{where}: [columns] time_unit must be 's' or 'ms'")


def load_map(path: str | Path) -> LogMap:
    """Read a mapping file; errors name the file and the key."""
    path = Path(path)
    data = read_toml(path, MAP_KIND, LogImportError)
    try:
        m = LogMap.model_validate(data)
    except ValidationError as exc:
        raise LogImportError(format_validation_error(exc, str(path))) from None
    m.check(str(path))
    return m


@dataclass
class _Log:
    path: str
    header: list[str]
    rows: list[list[str]]
    decimal: str = "."  #: "," when the log writes decimal commas
    lines: list[int] | None = None  #: the line each row starts on

    def line(self, i: int) -> int:
        return self.lines[i] if self.lines else i + 2

    def col(self, name: str) -> int:
        if name not in self.header:
            raise LogImportError(
                f"{self.path}: line 1: no column {name!r} (the header has: "
                f"{', '.join(self.header[:20])}{'…' if len(self.header) > 20 else ''})"
            )
        return self.header.index(name)

    def numbers(self, name: str) -> np.ndarray:
        j = self.col(name)
        out = np.empty(len(self.rows))
        for i, row in enumerate(self.rows):
            cell = row[j].strip() if j < len(row) else ""
            try:
                v = float(to_point(cell) if self.decimal == "," else cell)
            except ValueError:
                v = float("nan")
            if not np.isfinite(v):
                raise LogImportError(
                    f"{self.path}: line {self.line(i)}, column {name!r}: {cell!r} is not a finite "
                    f"number{grouping_hint(cell)}"
                )
            out[i] = v
        return out

    def text(self, name: str) -> np.ndarray:
        j = self.col(name)
        return np.array([row[j].strip() if j < len(row) else "" for row in self.rows], dtype=object)


def _read_log(path: Path, numeric: list[str]) -> _Log:
    raw = read_bytes(path, LOG_KIND, LogImportError)
    dialect, text = table_text(raw, str(path), LogImportError, numeric, numeric)
    try:
        rows, lines = table_rows(text, dialect)
    except csv.Error as exc:
        raise LogImportError(
            f"{path}: line {exc.args[1]}: not valid CSV ({exc.args[0]}); fix the line or remove it"
        ) from None
    if len(rows) < 2:
        raise LogImportError(f"{path}: needs a header row and at least one row of data")
    header = [h.strip() for h in rows[0]]
    for r, line in zip(rows[1:], lines[1:], strict=True):
        if len(r) != len(header):
            raise LogImportError(
                f"{path}: line {line}: {len(r)} cells where the header has {len(header)}"
            )
    return _Log(str(path), header, rows[1:], dialect.decimal, lines[1:])


def import_log(log_path: str | Path, mapping: LogMap | str | Path) -> Measurements:
    """The measurement table of a lab's log (see the module docstring)."""
    m = mapping if isinstance(mapping, LogMap) else load_map(mapping)
    log = _read_log(Path(log_path), m.numeric_columns())
    p, r, c = m.pose, m.readings, m.columns
    position = (
        np.column_stack([log.numbers(n) for n in p.position]) * POSITION_UNITS[p.position_unit]
    )
    if p.quaternion is not None:
        q = np.column_stack([log.numbers(n) for n in p.quaternion])
        norm = np.linalg.norm(q, axis=1)
        bad = np.where(np.abs(norm - 1.0) > 1e-3)[0]
        if len(bad):
            i = int(bad[0])
            raise LogImportError(
                f"{log.path}: line {log.line(i)}, columns {', '.join(p.quaternion)}: quaternion norm "
                f"{norm[i]:.6f}, expected 1 — check quaternion_order ({p.quaternion_order})"
            )
        rot = Rotation.from_quat(q, scalar_first=p.quaternion_order == "wxyz")
    else:
        assert p.euler is not None
        angles = np.column_stack([log.numbers(n) for n in p.euler])
        rot = Rotation.from_euler(p.euler_sequence, angles, degrees=p.euler_unit == "deg")
    raw = np.column_stack([log.numbers(n) for n in r.columns]) - np.asarray(r.zero)
    if r.unit in SCALED_UNITS:
        readings = raw * np.asarray(r.mm_per_unit)
    else:
        readings = raw * LINEAR_UNITS[r.unit]
    n = len(log.rows)
    t = np.arange(n, dtype=float)
    if c.time:
        t = log.numbers(c.time) * (1e-3 if c.time_unit == "ms" else 1.0)
    leg = np.zeros(n, int) if not c.leg else log.numbers(c.leg).astype(int)
    constraint = (
        np.array([Constraint.FREE.value] * n, dtype=object)
        if not c.constraint
        else log.text(c.constraint)
    )
    unknown = sorted(set(constraint.tolist()) - set(CONSTRAINTS))
    if unknown:
        i = int(np.where(constraint == unknown[0])[0][0])
        raise LogImportError(
            f"{log.path}: line {log.line(i)}, column {c.constraint!r}: {unknown[0]!r} is not a "
            f"constraint ({', '.join(CONSTRAINTS)})"
        )
    # A column not mapped is left to from_arrays' default (None).
    step = log.text(c.step) if c.step else None
    pose_id = log.numbers(c.pose_id).astype(np.int64) if c.pose_id else None
    temperature = log.numbers(c.temperature) if c.temperature else None
    try:
        return Measurements.from_arrays(
            position,
            rot,
            readings,
            leg=leg,
            constraint=constraint,
            t=t,
            step=step,
            pose_id=pose_id,
            temperature=temperature,
        )
    except ValueError as exc:
        raise LogImportError(f"{log.path}: {exc}") from None
