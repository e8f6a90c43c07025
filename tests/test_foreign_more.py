"""More effects outside the catalogue (hexcal.sim.foreign_more) and their sessions
(hexcal.sim.foreign_cases): each hook does what its physics says, each session is the same for
the same seed, and each is sized so that Model 42 leaves at least twice the noise floor on
held-out poses — the contract the explorer's benchmark (benchmarks/diagnosis_rates.py) rests
on."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hexcal.diagnosis import diagnose
from hexcal.io.measurements import write_measurements
from hexcal.io.measurements_csv import read_measurements
from hexcal.sim import foreign_cases as fc
from hexcal.sim import verdict_cases as vc
from hexcal.sim.foreign_more import (
    angle_pull,
    cross_talk,
    joint_seating,
    knock_tracker,
    leg_inclination,
    platform_angle,
    stroke_cycle,
    turn_friction,
)
from hexcal.sim.simulate import PoseContext


def _ctx(rotvecs_deg: np.ndarray) -> PoseContext:
    n = len(rotvecs_deg)
    rot = Rotation.from_rotvec(np.deg2rad(rotvecs_deg)).as_matrix()
    return PoseContext(np.zeros((n, 3)), rot, np.arange(n, dtype=float), np.full(n, 20.0))


def test_platform_angles_are_the_exports_euler_angles_and_the_tilt_of_the_normal():
    ctx = _ctx(np.array([[0.0, 0.0, 10.0], [5.0, 0.0, 0.0], [0.0, -7.0, 0.0], [3.0, 4.0, 0.0]]))
    assert platform_angle(ctx.rotation[:3], "yaw") == pytest.approx([10, 0, 0], abs=1e-9)
    assert platform_angle(ctx.rotation[:3], "roll") == pytest.approx([0, 5, 0], abs=1e-9)
    assert platform_angle(ctx.rotation[:3], "pitch") == pytest.approx([0, 0, -7], abs=1e-9)
    # A turn about a horizontal axis tilts the normal by its angle, whatever the axis.
    assert platform_angle(ctx.rotation, "tilt") == pytest.approx([0, 5, 7, 5], abs=1e-9)
    with pytest.raises(ValueError, match="no platform angle 'spin'"):
        platform_angle(ctx.rotation, "spin")


def test_the_yaw_cable_follows_the_yaw_on_every_leg_about_its_mean():
    ctx = _ctx(np.array([[0.0, 0.0, -10.0], [0.0, 0.0, 0.0], [0.0, 0.0, 10.0]]))
    coef = np.arange(1, 7) * 1e-3
    out = angle_pull("yaw", coef)(np.zeros((3, 6)), ctx)
    np.testing.assert_allclose(out, np.outer([-10.0, 0.0, 10.0], coef), atol=1e-12)


def test_cross_talk_moves_one_leg_with_anothers_reading():
    readings = np.tile(np.linspace(30.0, 90.0, 5)[:, None], (1, 6))
    readings[:, 3] = [40.0, 50.0, 60.0, 70.0, 80.0]
    out = cross_talk(2, 4, 0.001, 60.0)(readings, _ctx(np.zeros((5, 3))))
    np.testing.assert_allclose(out[:, 1], [-0.02, -0.01, 0.0, 0.01, 0.02], atol=1e-15)
    assert not np.delete(out, 1, axis=1).any()
    with pytest.raises(ValueError, match="two legs"):
        cross_talk(3, 3, 0.001, 60.0)


def test_turn_friction_follows_the_direction_of_the_platforms_last_turn_not_its_angle():
    # yaw 0 → 4 → 8 → 6 → 6 (still) → 9°: turning up, up, down, (kept), up
    yaw = np.array([0.0, 4.0, 8.0, 6.0, 6.0, 9.0])
    ctx = _ctx(np.column_stack([np.zeros(6), np.zeros(6), yaw]))
    coef = np.array([0.03, -0.02, 0.0, 0.01, 0.04, -0.03])
    out = turn_friction("yaw", coef)(np.full((6, 6), 60.0), ctx)
    s = np.array([0.0, 1.0, 1.0, -1.0, -1.0, 1.0])
    np.testing.assert_allclose(out, s[:, None] * coef[None, :], atol=1e-12)
    # the same poses turned in roll instead: the yaw's friction sees no turn
    still = _ctx(np.column_stack([yaw, np.zeros(6), np.zeros(6)]))
    np.testing.assert_allclose(turn_friction("yaw", coef)(np.full((6, 6), 60.0), still), 0.0)


def test_joint_seating_is_nothing_at_home_and_grows_as_the_legs_inclination_squared():
    c = vc.foreign("joint seating", 2)
    truth = c.design
    home = np.array([truth.home.position, np.add(truth.home.position, [15.0, 0.0, 0.0])])
    ctx = PoseContext(home, np.stack([np.eye(3)] * 2), np.zeros(2), np.full(2, 20.0))
    coef = np.full(6, 0.001)
    out = joint_seating(truth, coef)(np.zeros((2, 6)), ctx)
    np.testing.assert_allclose(out[0], 0.0, atol=1e-12)
    dtheta = np.diff(leg_inclination(truth, ctx.position, ctx.rotation), axis=0)[0]
    np.testing.assert_allclose(out[1], coef * dtheta**2, rtol=1e-12)
    assert np.abs(dtheta).min() > 0.5  # the move leans every leg: the test sees the square


def test_the_cycle_repeats_at_its_period_and_not_at_the_lead_screws():
    r = np.tile(np.linspace(0.0, 100.0, 41)[:, None], (1, 6))
    hook = stroke_cycle(fc.CYCLE_MM, np.full(6, 0.01), np.linspace(0, 3, 6))
    ctx = _ctx(np.zeros((41, 3)))
    np.testing.assert_allclose(hook(r + fc.CYCLE_MM, ctx), hook(r, ctx), atol=1e-12)
    assert np.abs(hook(r + 5.0, ctx) - hook(r, ctx)).max() > 0.01


def test_a_knocked_tracker_moves_every_later_pose_rigidly_and_no_reading():
    c = vc.foreign("yaw cable", 1)
    row = 100
    knocked = knock_tracker(c.meas, row, np.array([0.0, 0.006, 0.0]), np.array([0.03, 0, 0]))
    np.testing.assert_array_equal(knocked.readings, c.meas.readings)
    np.testing.assert_array_equal(knocked.position[:row], c.meas.position[:row])
    # Rigid: distances between later poses kept (to the 1e-5 mm the positions are written at),
    # relative orientations kept, and the move is the one asked for.
    d0 = np.linalg.norm(c.meas.position[row:, None] - c.meas.position[None, row:], axis=-1)
    d1 = np.linalg.norm(knocked.position[row:, None] - knocked.position[None, row:], axis=-1)
    assert np.abs(d1 - d0).max() < 2e-5
    moved = knocked.rotations[row:] * c.meas.rotations[row:].inv()
    np.testing.assert_allclose(np.rad2deg(moved.magnitude()), 0.006, atol=1e-6)
    with pytest.raises(ValueError, match="outside"):
        knock_tracker(c.meas, 0, np.zeros(3), np.zeros(3))


def test_the_user_column_is_written_and_follows_neither_time_nor_temperature(tmp_path):
    c = vc.foreign("user column", 3)
    (name,) = c.covariates[0]
    assert name in {n for n, *_ in fc.USER_COLUMNS}
    assert c.meas.columns[-1] == name
    write_measurements(c.meas, tmp_path / "measurements.csv")
    assert read_measurements(tmp_path / "measurements.csv") == c.meas
    v = c.meas.extra[name].astype(float)
    assert v.std() > 0
    for other in (c.meas.t, c.meas.temperature):
        # Projected out before rounding to the column's decimals: what rounding leaves.
        assert abs(np.corrcoef(v, other)[0, 1]) < 0.01


def test_uneven_heating_comes_with_a_room_whose_temperature_is_not_the_time():
    """The temperature rises then falls, so a curve in time is not a curve in temperature."""
    c = vc.foreign("uneven heating", 4)
    temp = c.meas.temperature
    peak = int(np.argmax(temp))
    assert 0.25 * len(temp) < peak < 0.75 * len(temp)
    assert temp[-10:].mean() < temp[peak] - 0.5
    assert c.covariates == (("time",),)


@pytest.mark.parametrize("case", list(fc.MORE))
def test_each_session_is_built_and_the_same_for_the_same_seed(case):
    a, b = vc.foreign(case, 5), vc.foreign(case, 5)
    assert a.meas == b.meas
    assert a.covariates == b.covariates and a.frame_row == b.frame_row
    assert vc.foreign(case, 6).meas != a.meas
    accepted = fc.MORE[case]
    assert len(a.covariates) == len(accepted)
    for own, names in zip(a.covariates, accepted, strict=True):
        assert len(own) == 1 and own[0] in names
    if case == "tracker knocked":
        assert a.expected == "frame_step"
        assert len(a.meas) // 4 <= a.frame_row < 3 * len(a.meas) // 4
    else:
        assert a.expected == "unexplained" and a.frame_row is None


@pytest.mark.slow
@pytest.mark.parametrize("case", list(fc.MORE))
def test_model_42_leaves_at_least_twice_the_floor_on_held_out_poses(case):
    """The sizing contract: every seed's draw is at least 2× the floor (the benchmark's sizing
    check over 10 seeds showed the smallest draw; here two seeds)."""
    for seed in (0, 1):
        c = vc.foreign(case, seed)
        d = diagnose(c.meas, c.design, 42, instruments=c.instruments)
        assert d.fit.cv_rms_mm / d.noise_floor_mm >= 2.0, (seed, d.fit.cv_rms_mm)
