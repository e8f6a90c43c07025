"""The periodogram of a residual against the reading (hexcal.diagnosis.periodogram): the
amplitude and period of a ripple, scipy's Lomb–Scargle to 1e-9, and a noise line that white
noise crosses as often as it says."""

from __future__ import annotations

import numpy as np
import pytest

from hexcal.diagnosis.periodogram import (
    FALSE_ALARM,
    false_alarm,
    period_grid,
    periodogram,
    periodogram_and_level,
)


def test_periodogram_finds_a_sinusoid_at_its_period_and_amplitude():
    rng = np.random.default_rng(0)
    x = np.sort(rng.uniform(0, 100, 300))
    y = 3.0 * np.sin(2 * np.pi * x / 5.0 + 0.4) + 1.0 + rng.normal(0, 0.1, x.size)
    periods = np.array([4.0, 5.0, 6.5])
    amp = periodogram(x, y, periods)
    # a sinusoid's amplitude fitted to N readings of noise σ has σ·√(2/N): within 4 of it
    assert amp[1] == pytest.approx(3.0, abs=4 * 0.1 * np.sqrt(2 / x.size))
    assert amp[0] < 0.5 and amp[2] < 0.5


@pytest.mark.parametrize("n", [8, 57, 400])
def test_periodogram_is_scipys_floating_mean_amplitude(n):
    """The written-out periodogram against scipy.signal.lombscargle (what it replaces, to spare
    the report scipy.signal's import): uneven readings, an offset, noise and a ripple; the
    frequency blocks are exercised by a grid longer than one block at N = 400."""
    from scipy.signal import lombscargle

    rng = np.random.default_rng(n)
    x = np.sort(rng.uniform(-40, 60, n))
    y = 7.0 + 2.0 * np.cos(2 * np.pi * x / 3.3) + rng.normal(0, 1.0, n)
    periods = 1.0 / np.linspace(1 / 20, 1 / 0.5, 6000)
    ref = np.abs(lombscargle(x, y, 2 * np.pi / periods, normalize="amplitude", floating_mean=True))
    np.testing.assert_allclose(periodogram(x, y, periods), ref, rtol=1e-9, atol=1e-12 * ref.max())


@pytest.mark.parametrize(
    "n, span", [(30, 10.0), (60, 40.0), pytest.param(300, 150.0, marks=pytest.mark.slow)]
)
def test_white_noise_crosses_the_noise_line_as_often_as_it_says(n, span):
    """Over 500 legs of white noise (``n`` readings spread over ``span`` mm) the periodogram
    crosses the noise level somewhere in the band in FALSE_ALARM (1 %) of them: 5 ± 2.2
    expected, 1 to 13 allowed (13 is 3.6σ above). The flat line it replaces — span·Δf
    independent frequencies, one amplitude for all — was crossed in 4–6 % of the 60-reading
    legs and 14 % of the 30-reading ones; it fails here."""
    rng = np.random.default_rng(n)
    sigma, trials = 2.0, 500
    crossed = 0
    for _ in range(trials):
        x = np.sort(rng.uniform(0.0, span, n))
        y = rng.normal(0.0, sigma, n)
        periods = period_grid(float(np.ptp(x)))
        amp, level = periodogram_and_level(x, y, periods, sigma)
        crossed += bool(np.any(amp > level))
    assert 1 <= crossed <= 13, f"{crossed} of {trials} noise-only legs crossed the line"


def test_the_noise_level_is_flat_where_the_readings_sample_every_period():
    """Evenly spread readings resolve every period in the band (M = I/2): the level is the
    flat √(4 z* σ² / N) with z* from Baluev's bound; and z* gives FALSE_ALARM back."""
    x = np.linspace(0.0, 100.0, 2001)
    periods = period_grid(100.0)
    _, level = periodogram_and_level(x, np.zeros_like(x), periods, 3.0)
    assert np.ptp(level) / level.mean() < 0.01
    z = level.mean() ** 2 * len(x) / (4 * 3.0**2)
    assert float(false_alarm(z, x)) == pytest.approx(FALSE_ALARM, rel=0.02)


def test_one_pass_gives_the_periodogram_and_its_level():
    rng = np.random.default_rng(4)
    x = np.sort(rng.uniform(0.0, 80.0, 150))
    y = rng.normal(0.0, 2.0, 150)
    periods = period_grid(float(np.ptp(x)))
    amp, level = periodogram_and_level(x, y, periods, 2.0)
    np.testing.assert_array_equal(amp, periodogram(x, y, periods))
    assert np.all(np.isfinite(level)) and np.all(level > 0)
