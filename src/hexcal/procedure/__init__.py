"""A calibration as the operator runs it: procedure files and their steps, recording poses, the
session file, the guided engine.

Here, light to import: :func:`looks_like_session`, which a command asks of every input file before
it knows whether it needs :mod:`hexcal.procedure.session` (pydantic's session models, the
devices, the acquisition).
"""

from __future__ import annotations

from pathlib import Path


def looks_like_session(path: str | Path) -> bool:
    """True when ``path`` is a JSON file whose first bytes open a session object."""
    path = Path(path)
    if path.suffix.lower() != ".json":
        return False
    try:
        with path.open("rb") as fh:
            head = fh.read(4096)
    except OSError:
        return False
    return b'"schema_version"' in head
