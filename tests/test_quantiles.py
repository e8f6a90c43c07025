"""hexcal.estimate.quantiles against scipy.stats, which it replaces (for the import time): the
same numbers over the arguments hexcal uses and well beyond them."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy import stats

from hexcal.estimate import quantiles

PROBS = [1e-12, 1e-6, 0.001, 0.01, 0.025, 0.05, 0.3, 0.5, 0.7, 0.95, 0.975, 0.99, 0.999, 1 - 1e-9]
DFS = [0.5, 1, 2, 3, 6, 7, 13, 42, 100, 252, 1314, 10_000, 1e6]


def close(a: float, b: float) -> bool:
    return bool(np.isclose(a, b, rtol=1e-12, atol=0.0))


@pytest.mark.parametrize("df", DFS)
def test_chi2_quantiles_and_tail_match_scipy_stats(df):
    for p in PROBS:
        assert close(quantiles.chi2_ppf(p, df), stats.chi2.ppf(p, df)), (p, df)
        assert close(quantiles.chi2_isf(p, df), stats.chi2.isf(p, df)), (p, df)
    for x in [1e-6, 0.1, 1.0, 5.0, df, 2 * df + 10, 10 * df + 100]:
        assert close(quantiles.chi2_sf(x, df), stats.chi2.sf(x, df)), (x, df)


@pytest.mark.parametrize("df", DFS)
def test_t_quantile_matches_scipy_stats(df):
    for p in PROBS:
        assert close(quantiles.t_ppf(p, df), stats.t.ppf(p, df)), (p, df)


def test_normal_quantile_and_density_match_scipy_stats():
    p = np.array(PROBS)
    np.testing.assert_allclose(quantiles.norm_ppf(p), stats.norm.ppf(p), rtol=1e-12, atol=0)
    assert close(quantiles.norm_ppf(0.975), stats.norm.ppf(0.975))
    x = np.linspace(-8, 8, 161)
    np.testing.assert_allclose(quantiles.norm_pdf(x), stats.norm.pdf(x), rtol=1e-12, atol=0)


def test_the_values_hexcal_uses():
    """The clamp test's limit, the outlier threshold, the robust noise level's median and the
    95 % intervals: exactly what scipy.stats gave."""
    from hexcal.diagnosis.outliers import OUTLIER_ALPHA
    from hexcal.estimate.calibrate import CLAMP_TEST_P

    for df in (1, 18, 252, 500):
        assert close(quantiles.chi2_ppf(1 - CLAMP_TEST_P, df), stats.chi2.ppf(1 - CLAMP_TEST_P, df))
    for m in (1, 40, 184, 1000):
        assert close(quantiles.chi2_isf(OUTLIER_ALPHA / m, 6), stats.chi2.isf(OUTLIER_ALPHA / m, 6))
    assert close(quantiles.chi2_ppf(0.5, 6), stats.chi2.median(6))
    for dof in (1, 30, 1314):
        assert close(quantiles.t_ppf(0.975, dof), stats.t.ppf(0.975, dof))


def test_calibrating_does_not_load_scipy_stats():
    """The reason for the module: scipy.stats costs 0.3–0.4 s of every command's start."""
    code = (
        "import sys; import hexcal.app.workflow, hexcal.app.report_text, "
        "hexcal.diagnosis.outliers, hexcal.app.demo; "
        "print('scipy.stats' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
