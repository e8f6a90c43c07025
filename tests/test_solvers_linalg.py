"""Batched least squares: the nested systems of ``lstsq(rows=...)``."""

from __future__ import annotations

import numpy as np
import pytest

from hexcal.estimate.solvers.linalg import lstsq, running_sums


def test_rows_solve_each_leading_system_as_qr_does():
    rng = np.random.default_rng(3)
    # Columns of very different sizes, as the solvers' are (mm, mm², unit vectors).
    a = rng.normal(size=(7, 40, 5)) * np.array([1.0, 200.0, 1e-2, 3.0, 4e4])
    y = rng.normal(size=(7, 40))
    rows = [5, 6, 17, 40]
    x = lstsq(a, y, rows=rows)
    assert x.shape == (7, 4, 5)
    for i, r in enumerate(rows):
        want = lstsq(a[:, :r], y[:, :r], method="qr")
        np.testing.assert_allclose(x[:, i], want, rtol=1e-9, atol=0)


def test_rows_must_increase_within_the_system():
    a, y = np.ones((2, 6, 2)), np.ones((2, 6))
    with pytest.raises(ValueError, match="rows must increase"):
        lstsq(a, y, rows=[4, 3])
    with pytest.raises(ValueError, match="at most 6"):
        lstsq(a, y, rows=[7])


def test_running_sums_are_the_cumulative_sums_at_the_counts(rng):
    x = rng.normal(size=(5, 12, 3, 2))
    counts = [1, 2, 5, 11, 12]
    got = running_sums(x, counts, axis=1)
    assert got.shape == (5, 5, 3, 2)
    assert np.allclose(got, np.cumsum(x, axis=1)[:, np.asarray(counts) - 1], rtol=1e-13)
    assert np.allclose(running_sums(x, [3, 4], axis=-3), np.cumsum(x, axis=-3)[:, [2, 3]])
