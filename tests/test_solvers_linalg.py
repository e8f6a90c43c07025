"""Batched least squares: the nested systems of ``lstsq(rows=...)``."""

from __future__ import annotations

import numpy as np
import pytest

from hexcal.estimate.solvers.linalg import lstsq


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
