"""``hexcal predict``'s tables: readings → poses and poses → readings as CSV.

Input: a CSV with a header. To compute poses it needs ``rho1`` … ``rho6`` (mm); to compute
readings, ``x, y, z`` (mm) and ``qw, qx, qy, qz`` (scalar first) — the measurement table's
names, so a measurements.csv is a valid input. Optional ``t`` (s) and ``temperature`` (degC,
for a model with thermal expansion). Rows are taken in motion order (backlash). Output: the
input's columns with the computed ones replaced or added, 9 significant decimals.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, overload

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.errors import InputError
from hexcal.estimate.predict import LegModel
from hexcal.io.csv_dialect import table_rows, table_text, to_point
from hexcal.io.safe_read import (
    MAX_COORDINATE_MM,
    MAX_TEMPERATURE_C,
    MAX_TIME_S,
    MIN_TEMPERATURE_C,
    read_bytes,
)
from hexcal.io.validation import shown_value

READINGS = tuple(f"rho{k}" for k in range(1, 7))
POSE = ("x", "y", "z", "qw", "qx", "qy", "qz")
#: The range of each column's values (unit): as in measurements.csv (docs/formats.md).
_RANGES = {
    **{c: (-MAX_COORDINATE_MM, MAX_COORDINATE_MM, "mm") for c in (*READINGS, "x", "y", "z")},
    **{c: (-2.0, 2.0, "") for c in ("qw", "qx", "qy", "qz")},
    "t": (-MAX_TIME_S, MAX_TIME_S, "s"),
    "temperature": (MIN_TEMPERATURE_C, MAX_TEMPERATURE_C, "degC"),
}


class TableError(InputError):
    """The table cannot be read; the message names the file, line and column."""


@dataclass
class Table:
    """A CSV table as text: its header, its rows (blank ones left out) and the line each row
    starts on (header = line 1)."""

    path: str
    header: list[str]
    rows: list[list[str]]
    lines: list[int]
    decimal: str = "."  #: "," when the file writes decimal commas (a spreadsheet's locale)

    @overload
    def column(self, name: str, required: Literal[True] = True) -> np.ndarray: ...

    @overload
    def column(self, name: str, required: bool) -> np.ndarray | None: ...

    def column(self, name: str, required: bool = True) -> np.ndarray | None:
        if name not in self.header:
            if required:
                raise TableError(f"{self.path}: line 1: no column {name!r} in the header")
            return None
        j = self.header.index(name)
        low, high, unit = _RANGES.get(name, (-np.inf, np.inf, ""))
        out = np.empty(len(self.rows))
        for i, row in enumerate(self.rows):
            cell = row[j] if j < len(row) else ""
            where = f"{self.path}: line {self.lines[i]}, column {name!r}: {shown_value(cell)}"
            try:
                v = float(to_point(cell) if self.decimal == "," else cell)
            except ValueError:
                raise TableError(f"{where} is not a number") from None
            if not np.isfinite(v):
                raise TableError(f"{where} is not a finite number")
            if not low <= v <= high:
                raise TableError(f"{where} is outside {low:g}..{high:g} {unit}".rstrip())
            out[i] = v
        return out

    def has(self, names: tuple[str, ...]) -> bool:
        return all(n in self.header for n in names)


def read_table(path: Path) -> Table:
    """Read a prediction table (UTF-8 CSV with a header, at most 64 MB: every cell is kept as
    text to be written back). Errors name the file and the line."""
    path = Path(path)
    raw = read_bytes(path, "table", TableError)
    dialect, text = table_text(raw, str(path), TableError, (*READINGS, *POSE), list(_RANGES))
    try:
        rows, lines = table_rows(text, dialect)
    except csv.Error as exc:
        raise TableError(
            f"{path}: line {exc.args[1]}: not valid CSV ({exc.args[0]}); fix the line or remove it"
        ) from None
    if not rows:
        raise TableError(f"{path}: empty; expected a header row and one row per pose")
    header = [h.strip() for h in rows[0]]
    body = rows[1:]
    for r, line in zip(body, lines[1:], strict=True):
        if len(r) != len(header):
            raise TableError(
                f"{path}: line {line}: {len(r)} cells where the header has {len(header)}"
            )
    if not body:
        raise TableError(f"{path}: no rows after the header")
    return Table(str(path), header, body, lines[1:], dialect.decimal)


def direction(table: Table, to: str | None) -> str:
    """``"pose"`` or ``"readings"``: what to compute (``to``, or what the columns allow)."""
    if to is not None:
        return to
    has_r, has_p = table.has(READINGS), table.has(POSE)
    if has_r and not has_p:
        return "pose"
    if has_p and not has_r:
        return "readings"
    if has_r and has_p:
        raise TableError(
            f"{table.path}: has both the readings and the pose columns: say which to compute "
            "with --to pose or --to readings"
        )
    raise TableError(
        f"{table.path}: line 1: needs rho1..rho6 (to compute poses) or x, y, z, qw, qx, qy, qz "
        "(to compute readings)"
    )


def predict_table(
    model: LegModel, table: Table, to: str, temperature: float | None = None
) -> tuple[list[str], np.ndarray]:
    """(column names, (N, k) values) the model computes for the table."""
    t = table.column("t", required=False)
    temp = table.column("temperature", required=False)
    if temp is None and temperature is not None:
        temp = np.full(len(table.rows), float(temperature))
    if to == "pose":
        readings = np.column_stack([table.column(c) for c in READINGS])
        poses = model.poses(readings, t, temp)
        return list(POSE), np.column_stack([poses.position, poses.quaternion])
    cols = {c: table.column(c) for c in POSE}
    q = np.column_stack([cols[c] for c in POSE[3:]])
    norm = np.linalg.norm(q, axis=1)
    bad = np.where(np.abs(norm - 1.0) > 1e-3)[0]
    if len(bad):
        raise TableError(
            f"{table.path}: line {table.lines[bad[0]]}: quaternion norm {norm[bad[0]]:.6f}, "
            "expected 1 (scalar first: qw, qx, qy, qz)"
        )
    rot = Rotation.from_quat(q, scalar_first=True).as_matrix()
    position = np.column_stack([cols["x"], cols["y"], cols["z"]])
    rho = model.readings(position, rot, t, temp)
    return list(READINGS), rho


def write_table(table: Table, names: list[str], values: np.ndarray) -> str:
    """CSV text: the input's columns with ``names`` replaced (or appended) by ``values``."""
    header = list(table.header)
    for n in names:
        if n not in header:
            header.append(n)
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(header)
    for i, row in enumerate(table.rows):
        cells = dict(zip(table.header, row, strict=True))
        for j, n in enumerate(names):
            cells[n] = f"{values[i, j]:.9f}"
        w.writerow([cells[h] for h in header])
    return out.getvalue()
