"""The periodogram of a leg's residual against its reading: a lead screw's periodic error
shows as a peak at its pitch."""

from __future__ import annotations

import numpy as np

#: Periods searched by the periodogram, mm (a lead screw's pitch is typically 1–10 mm).
PERIOD_RANGE_MM = (0.5, 20.0)
#: False-alarm probability of the periodogram's noise line, over the whole band of one leg.
FALSE_ALARM = 0.01


def _sums(x: np.ndarray, omega: np.ndarray):
    """Per block of angular frequencies ``omega`` (F,) rad/mm at readings ``x`` (N,) mm: the
    slice of ``omega`` it covers, cos ωx and sin ωx (N, f), and the centred normal sums cc, ss,
    cs (f,) (divided by N) of the fit ``c + α cos ωx + β sin ωx``, with their determinant (NaN
    at a frequency the readings cannot resolve). Blocks keep memory at a few MB however many
    poses there are."""
    n = max(len(x), 1)
    step = max(1, 2_000_000 // n)
    for lo in range(0, len(omega), step):
        wx = np.multiply.outer(x, omega[lo : lo + step])  # (N, f)
        cos, sin = np.cos(wx), np.sin(wx)
        c, s = cos.mean(axis=0), sin.mean(axis=0)
        cc = np.einsum("nf,nf->f", cos, cos) / n - c * c
        ss = np.einsum("nf,nf->f", sin, sin) / n - s * s
        cs = np.einsum("nf,nf->f", cos, sin) / n - c * s
        det = cc * ss - cs * cs
        tiny = np.finfo(float).eps * np.maximum(cc * ss, np.finfo(float).tiny)
        yield slice(lo, lo + step), cos, sin, cc, ss, cs, np.where(det > tiny, det, np.nan)


def periodogram(reading: np.ndarray, resid: np.ndarray, periods: np.ndarray) -> np.ndarray:
    """Lomb–Scargle amplitude (same unit as ``resid``) of a sinusoid in ``resid`` (N,) against
    ``reading`` (N,) mm, at each of ``periods`` (F,) mm: the amplitude of the least-squares fit
    of ``c + α cos ωx + β sin ωx`` at ω = 2π / period, the mean ``c`` fitted with it (the
    generalised periodogram of Zechmeister & Kürster 2009, A&A 496, 577, eqs. 5–20, with equal
    weights: what ``scipy.signal.lombscargle(..., normalize="amplitude", floating_mean=True)``
    returns, which the tests check). Written out rather than imported because importing
    scipy.signal costs 0.4 s, a fifth of a report, for this one function."""
    amp, _ = _scan(np.asarray(reading, float), np.asarray(resid, float), periods, None)
    return amp


def periodogram_and_level(
    reading: np.ndarray, resid: np.ndarray, periods: np.ndarray, sigma: float
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`periodogram` of ``resid`` (N,) against ``reading`` (N,) mm at ``periods`` (F,) mm,
    and its noise level (F,): the amplitude that white noise of 1σ ``sigma`` crosses anywhere
    in the band with probability :data:`FALSE_ALARM` — in one pass over the frequencies (the
    cosines and sines of every reading at every frequency are most of either's time).

    Noise of σ gives the fit's (α, β) the covariance σ² M⁻¹/N (M the normal sums of
    :func:`_sums`), so its amplitude² averages σ² tr(M⁻¹)/N and the power z compares it with
    that: the level is √(z* σ² tr M⁻¹ / N), z* from :func:`false_alarm`. Where the readings
    sample a period well, M = I/2 and the level is flat, √(4 z* σ²/N); where they cannot
    resolve it, noise alone makes large amplitudes and the level rises with them (a flat line
    was crossed by noise in 14 % of 30-reading legs, not 1 %)."""
    x = np.asarray(reading, float)
    amp, level = _scan(x, np.asarray(resid, float), periods, _z_at_false_alarm(x))
    return amp, sigma * level


def _scan(
    x: np.ndarray, y: np.ndarray, periods: np.ndarray, z: float | None
) -> tuple[np.ndarray, np.ndarray]:
    """The amplitude of ``y`` and the noise level per unit σ at power ``z`` (NaN when None),
    each (F,), at ``periods`` (F,) mm."""
    amp = np.empty(len(periods))
    level = np.full(len(periods), np.nan)
    y = y - y.mean()  # the floating mean: every sum below is of centred quantities
    for sl, cos, sin, cc, ss, cs, det in _sums(x, 2 * np.pi / np.asarray(periods, float)):
        yc, ys = y @ cos / len(x), y @ sin / len(x)
        # The 2×2 normal equations [cc cs; cs ss] (α, β) = (yc, ys), solved in closed form.
        alpha = (ss * yc - cs * ys) / det
        beta = (cc * ys - cs * yc) / det
        amp[sl] = np.hypot(alpha, beta)
        if z is not None:
            level[sl] = np.sqrt(z * (cc + ss) / (len(x) * det))
    return amp, level


def period_grid(span: float) -> np.ndarray:
    """Periods (mm), uniform in frequency with 5 points per resolution element 1/span."""
    lo, hi = PERIOD_RANGE_MM
    n = int(np.clip(5 * span * (1 / lo - 1 / hi), 200, 20000))
    return 1.0 / np.linspace(1 / hi, 1 / lo, n)


def false_alarm(z: np.ndarray | float, reading: np.ndarray) -> np.ndarray:
    """The probability that white noise at ``reading`` (N,) mm lifts the periodogram's power
    z (half the χ² the sinusoid removes) above ``z`` anywhere in :data:`PERIOD_RANGE_MM`:
    Baluev's bound (2008, MNRAS 385, 1279, Table 1, the "psd" row), as astropy's
    ``LombScargle.false_alarm_probability(method="baluev")`` computes it. One frequency alone
    gives exp(−z); the band gives about W = Δf·√(4π var(reading)) tries, each worth √z more
    than a count of independent frequencies says."""
    z = np.asarray(z, float)
    lo, hi = PERIOD_RANGE_MM
    w = (1 / lo - 1 / hi) * np.sqrt(4 * np.pi * np.var(reading))
    return 1 - (1 - np.exp(-z)) * np.exp(-w * np.exp(-z) * np.sqrt(z))


def _z_at_false_alarm(reading: np.ndarray) -> float:
    """The power z that noise reaches anywhere in the band with probability
    :data:`FALSE_ALARM` (:func:`false_alarm` falls from 1 at z = 0 as z grows)."""
    from scipy.optimize import brentq  # loaded already by the fit that came before

    return float(brentq(lambda z: float(false_alarm(z, reading)) - FALSE_ALARM, 0.0, 200.0))
