"""The few quantiles and tail probabilities hexcal needs (χ², Student's t, the normal), from
:mod:`scipy.special`, the functions :mod:`scipy.stats` itself evaluates them with.

Importing :mod:`scipy.stats` costs 0.3–0.4 s (its hundred distributions are built and their
docstrings parsed on import), more than a whole ``hexcal calibrate``; these five functions cost
nothing beyond :mod:`scipy.special`, which the fit loads anyway. Each is the formula
``scipy.stats`` uses for it (``tests/test_quantiles.py`` compares them), for valid arguments: a
probability in [0, 1] and degrees of freedom > 0.
"""

from __future__ import annotations

import math

from scipy import special


def chi2_ppf(p: float, df: float) -> float:
    """The χ²(df) quantile at probability ``p`` (``scipy.stats.chi2.ppf(p, df)``)."""
    return float(2.0 * special.gammaincinv(df / 2.0, p))


def chi2_isf(q: float, df: float) -> float:
    """The χ²(df) value exceeded with probability ``q`` (``scipy.stats.chi2.isf(q, df)``)."""
    return float(special.chdtri(df, q))


def chi2_sf(x: float, df: float) -> float:
    """P(χ²(df) > x) (``scipy.stats.chi2.sf(x, df)``)."""
    return float(special.chdtrc(df, x))


def t_ppf(p: float, df: float) -> float:
    """Student's t quantile at probability ``p`` with ``df`` degrees of freedom
    (``scipy.stats.t.ppf(p, df)``)."""
    return float(special.stdtrit(df, p))


def norm_ppf(p):
    """The standard normal quantile at ``p``, a number or an array (``scipy.stats.norm.ppf``)."""
    return special.ndtri(p)


def norm_isf(q: float) -> float:
    """The standard normal's upper ``q`` quantile (``scipy.stats.norm.isf``)."""
    return float(-special.ndtri(q))


def norm_pdf(x):
    """The standard normal density at ``x``, a number or an array (``scipy.stats.norm.pdf``)."""
    import numpy as np

    return np.exp(-np.square(x) / 2.0) / math.sqrt(2.0 * math.pi)
