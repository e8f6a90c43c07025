"""The fitted poses' fingerprint: a copy of the poses is known in any order and through a
value's last bits, a grid step crossed included; another session's poses are not."""

from __future__ import annotations

import dataclasses

import numpy as np

from hexcal.io.pose_fingerprint import OFFSET, QUANTUM_MM, fingerprint, shared_rows
from hexcal.sim.robots import left_hand
from hexcal.sim.session_sim import SessionPlan, simulate_session


def _session(seed: int):
    return simulate_session(left_hand(), seed, SessionPlan())[0]


def test_a_reordered_renumbered_copy_is_known_pose_by_pose():
    meas = _session(3)
    fp = fingerprint(meas)
    copy = dataclasses.replace(
        meas.subset(slice(None, None, -1)), pose_id=np.arange(len(meas)) + 900
    )
    assert shared_rows(copy, fp).all()


def test_last_bits_changed_and_a_grid_step_crossed_still_match():
    meas = _session(3)
    fp = fingerprint(meas)
    # every value through a unit conversion and back (relative change ~1e-16) …
    conv = dataclasses.replace(
        meas, position=meas.position / 25.4 * 25.4, readings=meas.readings * 1e-3 * 1e3
    )
    assert shared_rows(conv, fp).all()
    # … and one pose's reading on a grid step, nudged to the other side of it by 1e-9 mm
    on_step = meas.readings.copy()
    on_step[0, 0] = (np.floor(on_step[0, 0] / QUANTUM_MM) - OFFSET) * QUANTUM_MM + 5e-10
    stepped = dataclasses.replace(meas, readings=on_step)
    below = on_step.copy()
    below[0, 0] -= 1e-9
    nudged = dataclasses.replace(meas, readings=below)
    assert shared_rows(nudged, fingerprint(stepped)).all()


def test_another_session_of_the_same_poses_shares_none():
    meas = _session(3)
    # the same commanded poses measured again: a 5 µm tracker and a 1 µm encoder tell them
    rng = np.random.default_rng(0)
    again = dataclasses.replace(
        meas,
        position=meas.position + rng.normal(0, 5e-3, meas.position.shape),
        readings=meas.readings + rng.normal(0, 1e-3, meas.readings.shape),
    )
    assert not shared_rows(again, fingerprint(meas)).any()
    assert not shared_rows(_session(4), fingerprint(meas)).any()
