"""A recorded series through a first-order lag (hexcal.effects.lagged), and its covariate."""

from __future__ import annotations

import numpy as np
import pytest

from hexcal.effects.lagged import first_order_lag, lag_name, lag_taus, parse_lag


def test_the_lag_is_the_exact_response_of_a_first_order_system():
    """A step in the series just after t₀ reaches 1 − e^(−(t − t₀)/τ) of it at each later time,
    however unevenly the poses are spaced (the exact discretisation of dy/dt = (x − y)/τ with
    each sample's value held over the interval that ends at it), and poses recorded out of
    order are filtered in time order."""
    t = np.array([0.0, 3.0, 10.0, 11.0, 40.0, 100.0])
    x = np.r_[0.0, np.ones(5)]
    y = first_order_lag(x, t, 20.0)
    np.testing.assert_allclose(y, 1.0 - np.exp(-(t - t[0]) / 20.0), rtol=0, atol=1e-15)
    order = np.array([3, 0, 5, 1, 4, 2])
    np.testing.assert_array_equal(first_order_lag(x[order], t[order], 20.0), y[order])


def test_a_long_lag_holds_and_a_short_one_follows():
    t = np.linspace(0.0, 1000.0, 200)
    x = np.sin(t / 50.0)
    assert np.max(np.abs(first_order_lag(x, t, 1e-3) - x)) < 1e-12
    assert np.ptp(first_order_lag(x, t, 1e9)) < 1e-6


@pytest.mark.parametrize("tau", [1.0, 37.0, 600.0])
def test_the_name_carries_the_time_constant(tau):
    assert parse_lag(lag_name("coolant_temp_c", tau)) == ("coolant_temp_c", tau)
    assert parse_lag(lag_name("temperature", tau + 0.4)) == ("temperature", tau)
    assert parse_lag("coolant_temp_c") is None


def test_the_time_constants_tried_are_shares_of_the_span():
    assert lag_taus(np.array([5.0, 1005.0])) == [30.0, 50.0, 80.0, 150.0, 250.0, 400.0]
    assert lag_taus(np.array([3.0, 3.0])) == []
