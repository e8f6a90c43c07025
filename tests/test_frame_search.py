"""The search for a rigid move of the measuring frame: a knock is a step, a settling stand a
curve (:func:`hexcal.diagnosis.frame_search.search_frame`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hexcal.diagnosis import diagnose
from hexcal.diagnosis.frame_search import search_frame
from hexcal.sim import verdict_cases as vc
from hexcal.sim.foreign_more import knock_tracker

#: The move: 0.025° about a horizontal axis and 100 µm, the foreign set's knock (KNOCK_DEG,
#: KNOCK_MM), 20–40× the tracker's 2.5 µm noise at the platform.
TURN_DEG = np.array([0.018, 0.018, 0.0])
SHIFT_MM = np.array([0.06, -0.05, 0.06])


def _settled(meas, tau_share: float):
    """``meas`` as a tracker whose stand settles by the move above along 1 − e^(−t/τ), τ a
    share of the session's span: every pose moved rigidly by its share of the move."""
    t = np.asarray(meas.t, float)
    s = 1.0 - np.exp(-(t - t[0]) / (tau_share * np.ptp(t)))
    turn = Rotation.from_rotvec(np.deg2rad(s[:, None] * TURN_DEG))
    position = turn.apply(meas.position) + s[:, None] * SHIFT_MM
    q = (turn * Rotation.from_quat(meas.quaternion, scalar_first=True)).as_quat(scalar_first=True)
    return dataclasses.replace(meas, position=np.round(position, 5), quaternion=np.round(q, 9))


@pytest.fixture(scope="module")
def clean():
    return vc.absorbed("tracker scale", 0)  # a scale of 30–100 ppm: below the noise here


def _search(case, meas):
    d = diagnose(meas, case.design, 42, instruments=case.instruments)
    return search_frame(d.problem, d.fit, d.fit.chi2 / d.fit.dof)


def test_a_knock_is_found_at_its_pose(clean):
    row = len(clean.meas) // 2
    change = _search(clean, knock_tracker(clean.meas, row, TURN_DEG, SHIFT_MM))
    assert change is not None and abs(change.index - row) <= 3


@pytest.mark.parametrize("tau_share", [0.1, 0.3])
def test_a_stand_settling_smoothly_is_a_curve_not_a_knock(clean, tau_share):
    """The same move, reached smoothly: no split passes the threshold beyond a smooth drift
    of the move (before the gate, the search named a move of every leg at one pose)."""
    assert _search(clean, _settled(clean.meas, tau_share)) is None
