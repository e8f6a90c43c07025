"""Pydantic validation errors as messages an operator can act on."""

from __future__ import annotations

from pydantic import ValidationError


def format_validation_error(exc: ValidationError, where: str) -> str:
    """One line per problem: ``<where>: field legs.2.node_id: <what is wrong>``.

    ``where`` is usually the file's path, so every line names the file and the field.
    """
    lines = []
    for err in exc.errors():
        field = ".".join(str(p) for p in err["loc"]) or "(top level)"
        msg = err["msg"].removeprefix("Value error, ")
        lines.append(f"{where}: field {field}: {msg}")
    return "\n".join(lines)
