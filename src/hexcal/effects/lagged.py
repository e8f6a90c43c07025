"""A recorded series seen through a first-order lag: what a part follows when it takes time to
follow it (a leg's steel behind the air thermometer, an encoder behind its motor's current, a
mount behind the coolant's temperature).

A covariate ``NAME~lagTs`` is the series ``NAME`` (the ``temperature`` or an extra numeric
column of the table) filtered in recording time with the time constant T seconds:
``y₀ = x₀``, ``yᵢ = yᵢ₋₁ + (1 − e^(−(tᵢ − tᵢ₋₁)/T))·(xᵢ − yᵢ₋₁)``. The explorer tries
:data:`LAG_SHARES` of the session's span; the name carries T, so that an effect file written
for it evaluates the same quantity on the same poses. On another session the filter starts
again at its first pose (the part is taken to have settled before it).
"""

from __future__ import annotations

import re

import numpy as np

#: The time constants tried, as shares of the session's span.
LAG_SHARES = (0.03, 0.05, 0.08, 0.15, 0.25, 0.4)
_NAME = re.compile(r"^(?P<base>.+)~lag(?P<tau>\d+)s$")


def lag_name(base: str, tau_s: float) -> str:
    """The covariate name of ``base`` seen through a lag of ``tau_s`` seconds (whole s)."""
    return f"{base}~lag{max(round(tau_s), 1)}s"  # the time constant is the name's whole seconds


def parse_lag(name: str) -> tuple[str, float] | None:
    """(the series' name, the time constant in s) of a lagged covariate's name, else None."""
    m = _NAME.match(name)
    return None if m is None else (m["base"], float(m["tau"]))


def series_of(name: str) -> str:
    """The recorded series a covariate ``name`` is: a lagged covariate's own series, else the
    name itself."""
    lag = parse_lag(name)
    return name if lag is None else lag[0]


def lag_taus(t: np.ndarray) -> list[float]:
    """The time constants (s, whole) tried on a session recorded at times ``t`` (M,) s."""
    span = float(np.ptp(t)) if len(t) else 0.0
    return sorted({float(max(round(s * span), 1)) for s in LAG_SHARES}) if span > 0 else []


def first_order_lag(x: np.ndarray, t: np.ndarray, tau_s: float) -> np.ndarray:
    """(M,) the series ``x`` (M,) through a first-order lag of ``tau_s`` s, in the order of the
    times ``t`` (M,) s (poses recorded out of order are filtered in time order)."""
    x = np.asarray(x, float)
    order = np.argsort(np.asarray(t, float), kind="stable")
    ts, xs = np.asarray(t, float)[order], x[order]
    gain = 1.0 - np.exp(-np.diff(ts) / tau_s)
    y = np.empty_like(xs)
    if len(xs):
        y[0] = xs[0]
    for i in range(1, len(xs)):  # a recursion: each value needs the one before
        y[i] = y[i - 1] + gain[i - 1] * (xs[i] - y[i - 1])
    out = np.empty_like(y)
    out[order] = y
    return out
