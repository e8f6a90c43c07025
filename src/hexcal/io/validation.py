"""Pydantic validation errors as messages an operator can act on.

Pydantic's own text (``str(exc)``) is for programmers: it ends each problem with a link to
errors.pydantic.dev, counts problems, and puts the schema's inner names (``function-after[...]``,
``list[float]``, the members of a union) into the location. :func:`format_validation_error`
gives instead one line per problem naming the file and the field *as written in the file*, what
is wrong, the offending value when it is short, and what to do.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from typing import Any

from pydantic import ValidationError

_NO_DATA = object()
# Location parts pydantic adds for the schema, not the data: union members and wrapped types
# (``function-after[_unit(), list[float]]``, ``list[float]``, ``int``, ``str``...). Used only
# where the input itself is not at hand to tell data keys from them.
_SCHEMA_TAG = re.compile(
    r"[\w-]+\[.*\]|int|float|str|bool|bytes|none|list|dict|tuple|set|json|model|"
    r"constrained-\w+|lax-\w+|strict-\w+",
    re.DOTALL,
)
_PREFIXES = ("Value error, ", "Assertion failed, ")
_DEFAULT_HINTS = {
    "missing": "add it",
    "extra_forbidden": "remove it, or check its spelling",
}


def clean_location(loc: tuple[Any, ...], data: Any = _NO_DATA) -> tuple[Any, ...]:
    """``loc`` without the parts pydantic adds for its schema (union members, wrapped types).

    With the validated ``data`` at hand, a part is kept when it is a key or an index of the
    data at that point (or the last part: a missing key); otherwise it is a schema tag."""
    out: list[Any] = []
    node = data
    for i, part in enumerate(loc):
        last = i == len(loc) - 1
        if isinstance(node, dict):
            if part in node:
                out.append(part)
                node = node[part]
            elif last:
                out.append(part)
            continue  # a schema tag between two levels of the data
        if isinstance(node, (list, tuple)):
            if isinstance(part, int) and 0 <= part < len(node):
                out.append(part)
                node = node[part]
            continue
        node = _NO_DATA  # unknown input: tell tags by their form
        if not (isinstance(part, str) and _SCHEMA_TAG.fullmatch(part)):
            out.append(part)
    return tuple(out)


def shown_value(value: Any, kind: str = "") -> str | None:
    """A short text of an offending input for a message, or None when not worth showing.

    Numbers as a file writes them (``NaN``, ``1e+300``; numpy scalars as plain numbers), text
    quoted and cut at 40 characters, ``null``/``true``/``false`` as in JSON; an object or a
    list only named, and only when its type was the problem."""
    if hasattr(value, "item") and type(value).__module__ == "numpy":
        value = value.item()  # np.float64(nan) would otherwise print as such
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        if value.bit_length() > 128:
            return f"an integer of about {int(value.bit_length() * math.log10(2)) + 1} digits"
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "NaN"
        if math.isinf(value):
            return "Infinity" if value > 0 else "-Infinity"
        return repr(value)
    if isinstance(value, str):
        return repr(value if len(value) <= 40 else value[:40] + "…")
    if kind.endswith("_type") or kind.endswith("_parsing"):
        if isinstance(value, dict):
            return "an object"
        if isinstance(value, (list, tuple)):
            return f"a list of {len(value)} item(s)"
    return None


def field_name(loc: tuple[Any, ...]) -> str:
    """``field legs.2.node_id`` (indices from 0), or ``(top level)``."""
    return "field " + (".".join(str(p) for p in loc) or "(top level)")


def format_validation_error(
    exc: ValidationError,
    where: str,
    data: Any = _NO_DATA,
    *,
    locate: Callable[[tuple[Any, ...]], str] = field_name,
    hint: Callable[[tuple[Any, ...], str], str | None] | None = None,
) -> str:
    """One line per problem: ``<where>: field legs.2.node_id: <what is wrong> (got 0x80);
    <what to do>``.

    ``where`` is usually the file's path, so every line names the file and the field.
    ``data`` is the validated input (the parsed file): with it the location is exactly the
    path in the file. ``locate`` renders a location (e.g. "step 2 (id 'x'), field min_poses");
    ``hint(loc, error_type)`` says what to do, or None for the default. Problems a union's
    members report at one location become one line ("... or ...")."""
    grouped: dict[tuple[Any, ...], list[tuple[str, str, Any]]] = {}
    for err in exc.errors(include_url=False):
        loc = clean_location(tuple(err["loc"]), data)
        msg = err["msg"]
        for prefix in _PREFIXES:
            msg = msg.removeprefix(prefix)
        grouped.setdefault(loc, []).append((err["type"], msg, err.get("input")))
    lines = []
    for loc, problems in grouped.items():
        msgs = list(dict.fromkeys(m for _, m, _ in problems))
        kind, _, value = problems[0]
        text = " or ".join(msgs)
        if kind not in ("missing", "extra_forbidden"):
            got = shown_value(value, kind)
            if got is not None and "got " not in text:  # a message may show it already
                text += f" (got {got})"
        todo = hint(loc, kind) if hint is not None else None
        todo = todo or _DEFAULT_HINTS.get(kind)
        if todo:
            text += f"; {todo}"
        lines.append(f"{where}: {locate(loc)}: {text}")
    return "\n".join(lines)
