"""The plain measurement table read straight into column arrays.

A table as hexcal, a tracker's export or a spreadsheet writes it — no quoted field, every row
valid — is parsed by numpy's compiled CSV reader (``numpy.loadtxt`` with one dtype per column)
into its typed columns, with no Python object per row or field, then checked by whole columns
against the rules of :class:`~hexcal.io.measurements_csv.MeasurementRow`. Anything else (a
quote, a bad or short row, a repeated pose id, text the fast parser and ``float()`` might read
differently) makes :func:`read_plain` answer None, and the streaming reader of
:mod:`hexcal.io.measurements_csv` reads the file instead and names every problem: this path
never produces an error message of its own, and what it accepts the other accepts alike.
"""

from __future__ import annotations

import csv
import io
import warnings
from pathlib import Path

import numpy as np

from hexcal.io.measurements import (
    _KNOWN_COLUMNS,
    CONSTRAINTS,
    POSITION_COLUMNS,
    QUATERNION_COLUMNS,
    QUATERNION_TOLERANCE,
    READING_COLUMNS,
    REQUIRED_COLUMNS,
    Measurements,
    _object_array,
)
from hexcal.io.safe_read import (
    MAX_COORDINATE_MM,
    MAX_POSE_ID,
    MAX_TEMPERATURE_C,
    MAX_TIME_S,
    MIN_TEMPERATURE_C,
)
from hexcal.vocabulary import Constraint

_INTEGER_COLUMNS = ("pose_id", "leg")
_TEXT_COLUMNS = ("step", "constraint")


def read_plain(raw: bytes, path: Path) -> Measurements | None:
    """The table in ``raw`` (the file's bytes, its size already checked), or None when it is
    not a plain, valid table (the streaming reader then reads it)."""
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        return None
    text = text.replace("\r\n", "\n")
    if '"' in text or "\r" in text:
        return None  # quoting, or line ends the csv module reads its own way
    head, sep, body = text.partition("\n")
    if max(map(len, text.split("\n"))) > csv.field_size_limit():
        return None  # a field may exceed what the csv module reads: it says so
    header = [f.strip() for f in head.split(",")]
    if not sep or len(set(header)) != len(header) or "" in header:
        return None
    if any(c not in header for c in REQUIRED_COLUMNS):
        return None
    dtype = [(f"c{k}", _dtype(name)) for k, name in enumerate(header)]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # numpy's note on blank lines (they are skipped)
            data = np.loadtxt(
                io.StringIO(body),
                delimiter=",",
                dtype=dtype,
                comments=None,
                quotechar=None,
                ndmin=1,
            )
    except (ValueError, OverflowError, TypeError):
        return None
    if data.shape[0] == 0:
        return None
    return _checked(data, header, path)


def _dtype(name: str) -> str:
    if name in _INTEGER_COLUMNS:
        return "i8"
    if name in _KNOWN_COLUMNS and name not in _TEXT_COLUMNS:
        return "f8"
    return "O"


def _texts(values: np.ndarray) -> np.ndarray:
    """Stripped text (an object array of the fields as read), one str object per distinct
    value: a step name is shared by many rows."""
    distinct, index = np.unique(values, return_inverse=True)
    stripped = _object_array([v.strip() for v in distinct.tolist()])
    return stripped[index.reshape(-1)]


def _within(values: np.ndarray, low: float, high: float) -> bool:
    return bool(np.all((values >= low) & (values <= high)))  # False for NaN too


def _checked(data: np.ndarray, header: list[str], path: Path) -> Measurements | None:
    """The columns as a :class:`Measurements` when every row keeps the rules, else None."""
    col = {name: data[f"c{k}"] for k, name in enumerate(header)}

    def floats(names: tuple[str, ...]) -> np.ndarray:
        return np.stack([col[c] for c in names], axis=1)

    pose_id, leg, t = col["pose_id"], col["leg"], col["t"]
    position, quaternion = floats(POSITION_COLUMNS), floats(QUATERNION_COLUMNS)
    readings = floats(READING_COLUMNS)
    ok = _within(pose_id, 1, MAX_POSE_ID) and _within(leg, 0, 6)
    ok = ok and _within(t, -MAX_TIME_S, MAX_TIME_S)
    ok = ok and _within(position, -MAX_COORDINATE_MM, MAX_COORDINATE_MM)
    ok = ok and _within(readings, -MAX_COORDINATE_MM, MAX_COORDINATE_MM)
    with np.errstate(over="ignore", invalid="ignore"):
        norm = np.sqrt(np.sum(quaternion * quaternion, axis=1))
    # As the streaming reader: a row at the tolerance's very edge is left to the row rules.
    edge = QUATERNION_TOLERANCE * (1 - 1e-9)
    ok = ok and _within(norm, 1.0 - edge, 1.0 + edge)
    temperature = col.get("temperature")
    if temperature is not None:
        ok = ok and _within(temperature, MIN_TEMPERATURE_C, MAX_TEMPERATURE_C)
    if not ok or len(np.unique(pose_id)) != len(pose_id):
        return None
    texts = {c: _texts(col[c]) for c in header if c not in _KNOWN_COLUMNS or c in _TEXT_COLUMNS}
    step, constraint = texts["step"], texts["constraint"]
    if not set(constraint.tolist()) <= set(CONSTRAINTS) or "" in set(step.tolist()):
        return None
    if np.any((constraint == Constraint.FREE.value) != (leg == 0)):
        return None
    return Measurements(
        pose_id=pose_id,
        t=t,
        step=step,
        leg=leg,
        constraint=constraint,
        position=position,
        quaternion=quaternion,
        readings=readings,
        temperature=temperature,
        extra={c: v for c, v in texts.items() if c not in _TEXT_COLUMNS},
        columns=tuple(header),
        source=str(path),
    )
