"""The session file held to the rules of the table it exports to (docs/formats.md).

A session's poses are the rows of its interchange table, so they keep the table's rules: unique
pose ids, a header (``columns``) with every required column once and no empty name, each pose's
extra cells under a column of that header, ``leg`` 0 exactly for a free pose, a non-empty step,
a quaternion of norm 1 within the table's tolerance. :func:`session_problems` lists what breaks
them, each line naming the pose and the field *as the session file has them*
(``pose 7 (field poses.6.pose_id)``); the loader refuses such a file, and
:meth:`~hexcal.procedure.session.SessionFile.add_pose` such a pose, so ``session export`` never
meets a table it cannot write.

The functions take the session's records duck-typed (``pose_id``, ``leg``, ``constraint``...),
so this module needs nothing of :mod:`hexcal.procedure.session`, which calls it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from hexcal.io.measurements import (
    OPTIONAL_COLUMNS,
    QUATERNION_TOLERANCE,
    REQUIRED_COLUMNS,
)
from hexcal.vocabulary import Constraint

_KNOWN = frozenset(REQUIRED_COLUMNS + OPTIONAL_COLUMNS)
#: At most this many problems are spelled out; the rest are counted.
MAX_PROBLEMS = 20


def columns_problems(columns: Sequence[str]) -> list[str]:
    """What is wrong with a session's ``columns`` (the table's header)."""
    out = []
    seen: dict[str, int] = {}
    for k, name in enumerate(columns):
        if not name.strip():
            out.append(f"field columns.{k}: an empty column name; remove it")
        elif name in seen:
            out.append(
                f"field columns.{k}: column '{name}' appears twice (columns.{seen[name]} and "
                f"columns.{k}); remove one"
            )
        else:
            seen[name] = k
    missing = [c for c in REQUIRED_COLUMNS if c not in seen]
    if missing:
        out.append(
            f"field columns: lacks {', '.join(missing)}; the table's header must name "
            f"{','.join(REQUIRED_COLUMNS)}"
        )
    return out


def pose_problems(record: Any, i: int, columns: Sequence[str], group: str = "poses") -> list[str]:
    """What keeps pose ``record`` (at ``group.i`` in the file) from being a row of the table
    with header ``columns``."""
    name = f"pose {record.pose_id}"
    at = f"{group}.{i}"
    out = []
    leg = int(record.leg)
    constraint = getattr(record.constraint, "value", record.constraint)
    if (leg == 0) != (constraint == Constraint.FREE.value):
        out.append(
            f"{name} (field {at}.constraint): constraint '{constraint}' with leg {leg}; free "
            "poses have leg 0, clamped ones leg 1..6"
        )
    if not str(record.step).strip():
        out.append(f"{name} (field {at}.step): the step is empty; name the procedure step")
    q = [float(v) for v in record.quaternion]
    norm = math.sqrt(sum(v * v for v in q))
    if abs(norm - 1.0) > QUATERNION_TOLERANCE:
        out.append(
            f"{name} (field {at}.quaternion): norm {norm:.6f}, not within "
            f"{QUATERNION_TOLERANCE:g} of 1 (scalar first: qw, qx, qy, qz)"
        )
    extras = set(columns) - _KNOWN
    for key in record.extra:
        if key not in extras:
            why = "a standard column" if key in _KNOWN else "not a column of the table"
            out.append(
                f"{name} (field {at}.extra.{key}): '{key}' is {why}; add it to columns or "
                "remove the cell"
            )
    return out


def duplicate_id_problems(poses: Iterable[Any], group: str = "poses") -> list[str]:
    """Poses whose id an earlier pose already has."""
    first: dict[int, int] = {}
    out = []
    for i, record in enumerate(poses):
        pid = int(record.pose_id)
        if pid in first:
            out.append(
                f"pose {pid} (field {group}.{i}.pose_id): the id repeats {group}.{first[pid]}'s; "
                "pose ids must be unique, as in the table: give it an unused id or remove one"
            )
        else:
            first[pid] = i
    return out


def session_problems(session: Any) -> list[str]:
    """Everything that keeps ``session`` (a :class:`~hexcal.procedure.session.Session`) from
    exporting its table, one line each (pose and field named)."""
    out = columns_problems(session.columns)
    out += duplicate_id_problems(session.poses)
    table = session.imported()
    if table is not None and session.poses:
        ids = np.array([int(r.pose_id) for r in session.poses], np.int64)
        for k in np.flatnonzero(np.isin(ids, table.pose_id)).tolist():
            out.append(
                f"pose {ids[k]} (field poses.{k}.pose_id): the id is an imported pose's (the "
                "pose block's); pose ids must be unique, as in the table: give it an unused id"
            )
    for i, record in enumerate(session.poses):
        out += pose_problems(record, i, session.columns)
    return out


def problems_text(where: str, problems: list[str], todo: str) -> str:
    """The refusal: one line per problem (the first :data:`MAX_PROBLEMS`) naming ``where``,
    then what to do."""
    lines = [f"{where}: {p}" for p in problems[:MAX_PROBLEMS]]
    if len(problems) > MAX_PROBLEMS:
        lines.append(f"{where}: … and {len(problems) - MAX_PROBLEMS} more problem(s)")
    return "\n".join(lines) + f"\n{todo}"
