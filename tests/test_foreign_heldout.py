"""The held-out set of effects outside the catalogue: every case builds a session hiding what
it says, the same for the same seed."""

from __future__ import annotations

import numpy as np
import pytest

from hexcal.sim.foreign_heldout import HELDOUT, heldout
from hexcal.sim.session_sim import simulate_session
from hexcal.sim.verdict_cases import _start


@pytest.mark.parametrize("case", list(HELDOUT))
def test_case_builds_the_same_for_the_same_seed(case):
    a, b = heldout(case, 3), heldout(case, 3)
    assert a.expected == "unexplained" and a.covariates == (HELDOUT[case],)
    np.testing.assert_array_equal(a.meas.position, b.meas.position)
    np.testing.assert_array_equal(a.meas.readings, b.meas.readings)
    assert a.meas.columns == b.meas.columns
    # the hidden effect changes the readings: the same session without it differs by more
    # than the 0.1 µm the readings are written to
    design, _, plan, truth = _start(3, 340_000)
    clean, _ = simulate_session(design, 3, plan, truth=truth)
    assert np.max(np.abs(a.meas.readings - clean.readings)) > 0.01


def test_lagged_column_is_written_by_its_name():
    c = heldout("lagged column", 0)
    assert "coolant_temp_c" in c.meas.columns
    assert len(c.meas.extra["coolant_temp_c"]) == len(c.meas)


def test_unknown_case_is_refused_with_the_cases_named():
    with pytest.raises(ValueError, match="yaw wrap"):
        heldout("no such", 0)
