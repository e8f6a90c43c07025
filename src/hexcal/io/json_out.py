"""Strict JSON out: every ``--json`` output and every JSON file hexcal writes is RFC 8259 JSON.

Python's ``json`` writes NaN and infinity as the bare tokens ``NaN`` and ``Infinity``, which
``jq``, JavaScript and every strict parser refuse. Here a quantity that could not be computed
becomes ``null``, and a key beside it, ``<key>_why``, says why (in a list, the list's own key
gets the ``_why``), so a reader knows a gap from a zero. Numpy scalars and arrays become plain
numbers and lists. The text is then written with ``allow_nan=False``: a non-finite number that
slipped past is an error, never a token.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

#: Why a value is null, when the producer said nothing more precise.
NOT_COMPUTED = "could not be computed (the calculation gave no finite number)"
#: The suffix of the key that says why its neighbour is null.
WHY = "_why"

#: ``why(key, where)``: the reason a non-finite value under ``key`` of the object ``where`` is
#: null, or None for :data:`NOT_COMPUTED`.
Reason = Callable[[str, Mapping[str, Any]], str | None]


def _finite(x: float) -> bool:
    return math.isfinite(x)


def _plain(obj: Any) -> Any:
    """Numpy scalars and arrays as Python numbers and lists; tuples as lists."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, tuple):
        return list(obj)
    return obj


def _has_gap(values: list[Any]) -> bool:
    for v in values:
        v = _plain(v)
        if isinstance(v, float) and not _finite(v):
            return True
        if isinstance(v, list) and _has_gap(v):
            return True
    return False


def strict(obj: Any, why: Reason | None = None) -> Any:
    """``obj`` with every non-finite float replaced by ``None`` and its reason beside it (see
    the module docstring); ``why`` gives reasons by key (None: :data:`NOT_COMPUTED`)."""
    obj = _plain(obj)
    if isinstance(obj, float):
        return obj if _finite(obj) else None
    if isinstance(obj, list):
        return [strict(v, why) for v in obj]
    if isinstance(obj, Mapping):
        out: dict[str, Any] = {}
        for key, value in obj.items():
            value = _plain(value)
            key = str(key)
            gap = (isinstance(value, float) and not _finite(value)) or (
                isinstance(value, list) and _has_gap(value)
            )
            out[key] = strict(value, why)
            if gap and f"{key}{WHY}" not in obj:
                reason = why(key, obj) if why is not None else None
                if isinstance(value, list):
                    reason = reason or f"the null values {NOT_COMPUTED}"
                out[f"{key}{WHY}"] = reason or NOT_COMPUTED
        return out
    return obj


def dumps(obj: Any, why: Reason | None = None, **kwargs: Any) -> str:
    """Strict JSON text of ``obj`` (see :func:`strict`); ``kwargs`` as for ``json.dumps``."""
    return json.dumps(strict(obj, why), allow_nan=False, **kwargs)


def _refuse_constant(token: str) -> Any:
    raise ValueError(f"{token} is not JSON (RFC 8259 has no NaN or Infinity)")


def loads_strict(text: str) -> Any:
    """Parse ``text`` as a strict reader would (``jq``, JavaScript): ``NaN``, ``Infinity`` and
    ``-Infinity`` are refused with :class:`ValueError`."""
    return json.loads(text, parse_constant=_refuse_constant)


def accuracy_reason(key: str, record: Mapping[str, Any]) -> str | None:
    """Why a pose-accuracy figure (``position_rms_mm``...) is null: the poses whose readings
    no pose closes."""
    failed = record.get("failed", record.get("poses_out_of_workspace"))
    if key.startswith(("position_", "orientation_")) and isinstance(failed, int) and failed:
        return (
            f"no pose to measure it on: the readings of none of the {failed} poses tried closed "
            "to a pose with this model"
        )
    if key.startswith("floor_"):
        return "no noise floor without stated noise (the floor would be the fit's own residual)"
    return None
