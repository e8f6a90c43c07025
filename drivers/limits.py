"""Bounds the drivers put on the durations and numbers they are given.

Every wait a driver makes is bounded: a timeout of ``inf`` (or NaN, or a huge number) would
either crash deep inside pyserial / ``threading`` (``OverflowError: timeout value is too large``)
or hang the acquisition for ever. The configuration files are validated where they are read;
the drivers check again here, so a value built in code cannot slip past either.
"""

from __future__ import annotations

import math

#: The longest timeout (s) any driver accepts. A tracker or a CAN node that has not answered in
#: a minute is not going to: the operator is better told than kept waiting.
MAX_TIMEOUT_S = 60.0


def check_duration(
    name: str, value: float, *, allow_zero: bool = False, maximum: float = MAX_TIMEOUT_S
) -> float:
    """``value`` (s) as a float when it is a finite number in (0, ``maximum``] — [0, ``maximum``]
    with ``allow_zero`` — else ValueError naming the parameter ``name`` and the bounds."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    low_ok = v >= 0.0 if allow_zero else v > 0.0
    if not (math.isfinite(v) and low_ok and v <= maximum):
        low = ">= 0" if allow_zero else "> 0"
        raise ValueError(
            f"{name} must be a finite number of seconds, {low} and <= {maximum:g} s, not {value!r}"
        )
    return v


__all__ = ["MAX_TIMEOUT_S", "check_duration"]
