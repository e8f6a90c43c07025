"""The rate studies as checks (slow): every case of benchmarks/diagnosis_rates.py (the verdict's
hard cases of verdict_rates.py among them) run again on 10 fresh sessions, and the poses'
stated uncertainty (benchmarks/coverage.py) on 10 sessions.

Each case's bound comes from the binomial spread of its full run (docs/diagnosis_rates.json,
50 sessions): p_lo, the one-sided 95 % Clopper–Pearson lower limit of the full run's rate, is
the lowest rate that run allows; the check fails when fewer than q sessions of 10 are right, q
the largest count with P(K < q) ≤ 10⁻³ for K ~ Binomial(10, p_lo) (≈ 3.3σ one-sided). At a full
run of 50/50, p_lo = 0.942 and q = 6; a case at its detection limit (thermal at 0.3×: 5/50)
gets q = 0 and checks nothing but that it runs. HEXCAL_RATE_SESSIONS sets the count.

The README's and docs/diagnosis.md's tables are checked (quick) to be generated from that file.
"""

from __future__ import annotations

import importlib.util
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

FULL = json.loads((ROOT / "docs" / "diagnosis_rates.json").read_text())["summary"]
N = int(os.environ.get("HEXCAL_RATE_SESSIONS", "10"))
#: Fresh seeds: the full run used 0..49.
SEEDS = range(1000, 1000 + N)
ALPHA = 1e-3


def lowest_count(right: float, sessions: int, n: int = N, alpha: float = ALPHA) -> int:
    """q: fewer than q right of ``n`` has probability ≤ ``alpha`` at the lowest rate the full
    run (``right`` of ``sessions``) allows at 95 % (Clopper–Pearson, one-sided)."""
    k = round(right * sessions)
    p_lo = 0.0 if k == 0 else float(stats.beta.ppf(0.05, k, sessions - k + 1))
    q = int(stats.binom.ppf(alpha, n, p_lo))
    return q if stats.binom.cdf(q - 1, n, p_lo) <= alpha else q - 1


def test_the_readme_and_the_docs_tables_are_generated_from_the_full_run():
    """README.md's table is benchmarks/rates_readme.py's from docs/diagnosis_rates.json, and
    docs/diagnosis.md's is diagnosis_rates.markdown's from it (regenerate with
    `python benchmarks/rates_readme.py --write` after a full run)."""
    from diagnosis_rates import markdown
    from rates_readme import readme_table

    readme = (ROOT / "README.md").read_text()
    assert readme_table(FULL) in readme
    n = {v["sessions"] for v in FULL.values()}
    assert len(n) == 1 and f"over {n.pop()} simulated sessions per case" in readme
    assert markdown(FULL) in (ROOT / "docs" / "diagnosis.md").read_text()


def test_the_bound_from_a_full_run():
    assert lowest_count(1.0, 50) == 6
    assert lowest_count(0.1, 50) == 0
    assert stats.binom.cdf(lowest_count(0.88, 50) - 1, 10, 0.88) < ALPHA


@pytest.mark.slow
@pytest.mark.parametrize("key", sorted(FULL))
def test_each_case_is_right_as_often_as_its_full_run(key):
    from diagnosis_rates import run_key

    rows = run_key(key, SEEDS)
    right = sum(bool(r["right"]) for r in rows)
    q = lowest_count(FULL[key]["right"], FULL[key]["sessions"])
    verdicts = sorted(str(r["verdict"]) for r in rows)
    assert right >= q, f"{key}: {right} of {N} right (at least {q}); verdicts {verdicts}"


@pytest.mark.slow
def test_the_poses_stated_uncertainty_covers_95_percent():
    """benchmarks/coverage.py's position_coverage_95 over 10 sessions: the mean within 4σ of
    0.95, σ the standard error from the sessions' own spread."""
    # By path: "coverage" is also the name of a package a test run may have imported.
    spec = importlib.util.spec_from_file_location(
        "coverage_bench", ROOT / "benchmarks" / "coverage.py"
    )
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    one_session = bench.one_session
    with tempfile.TemporaryDirectory() as tmp:
        cov = np.array([one_session(seed, None, Path(tmp))["coverage"] for seed in range(1, 11)])
    sigma = cov.std(ddof=1) / np.sqrt(len(cov))
    assert abs(cov.mean() - 0.95) < 4 * sigma, (cov.mean(), sigma)
