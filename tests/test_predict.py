"""The calibrated model as a predictor: readings → pose → readings round trips for every
catalogue effect, and the refusals (stroke, workspace, joints, a missing input)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hexcal.effects import CATALOGUE
from hexcal.estimate.predict import LegModel, Poses, PredictionError
from hexcal.sim.inject import realistic_values
from hexcal.sim.robots import left_hand

ROBOT = left_hand().model_copy(update={"platform_mass_kg": 25.0, "leadscrew_pitch_mm": 5.0})


def _poses(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """n poses in motion order around home (±20 mm, ±8°) and a rising temperature."""
    rng = np.random.default_rng(seed)
    P = np.asarray(ROBOT.home.position) + rng.uniform(-20, 20, (n, 3))
    R = Rotation.from_rotvec(rng.uniform(-0.14, 0.14, (n, 3))).as_matrix()
    return P, R, 20.0 + np.linspace(0.0, 4.0, n)


# zero_step and frame_step are changes during one session, located there and never carried
# into a model that predicts (of_the_session): no round trip to make.
PREDICTING = sorted(e for e in CATALOGUE if e not in ("zero_step", "frame_step"))


@pytest.mark.parametrize("effect", PREDICTING)
def test_readings_pose_readings_round_trip_for_every_effect(effect):
    """Noise-free: the readings for a pose, then the pose for those readings, then the readings
    again, agree to 1e-6 mm (and the pose to 1e-6 mm and rad), each effect at a realistic size
    (gain, thermal and compliance 10× it, to make the effect plain)."""
    rng = np.random.default_rng(3)
    values = realistic_values(effect, rng, ROBOT)
    if effect in ("gain", "thermal", "compliance"):
        values = 10 * values
    if effect == "offset":
        robot = ROBOT.with_geometry(ROBOT.a, ROBOT.b, ROBOT.offsets + values)
        model = LegModel(robot)
    else:
        model = LegModel(ROBOT, (effect,), values)
    P, R, T = _poses(150)
    rho = model.readings(P, R, temperature=T)
    poses = model.poses(rho, temperature=T)
    assert np.abs(poses.position - P).max() < 1e-6
    angle = Rotation.from_matrix(np.einsum("nji,njk->nik", R, poses.rotation)).magnitude()
    assert angle.max() < 1e-6
    again = model.readings(poses.position, poses.rotation, temperature=T)
    assert np.abs(again - rho).max() < 1e-6
    # The effect is really in the prediction: the plain geometry reads otherwise.
    if effect != "offset":
        plain = LegModel(ROBOT).readings(P, R)
        assert np.abs(plain - rho).max() > 1e-3


def test_the_model_closes_the_legs_it_was_given():
    """The pose computed from readings has exactly the model's lengths: geometric length ==
    reading + offset + effects, with compliance evaluated at that pose."""
    values = np.array([30.0])
    model = LegModel(ROBOT, ("compliance",), values)
    P, R, _ = _poses(40, seed=1)
    rho = model.readings(P, R)
    poses = model.poses(rho)
    lengths = model.lengths(rho, poses.position, poses.rotation)
    assert np.abs(model.geometric(poses.position, poses.rotation) - lengths).max() < 1e-9


def test_readings_beyond_the_stroke_are_refused_with_the_row():
    robot = ROBOT.model_copy(update={"leg_range_mm": [0.0, 100.0]})
    model = LegModel(robot)
    P, R, _ = _poses(5)
    rho = model.readings(P, R, check_limits=False)
    rho[3, 2] = 120.0
    with pytest.raises(PredictionError, match=r"row 4 .*beyond its stroke.*leg 3 reads 120"):
        model.poses(rho)
    far = P.copy()
    far[1, 2] += 120.0
    with pytest.raises(PredictionError, match=r"poses: row 2 put a leg beyond its stroke"):
        model.readings(far, R)


def test_lengths_no_pose_closes_are_refused_as_outside_the_workspace():
    model = LegModel(ROBOT)
    P, R, _ = _poses(3)
    rho = model.readings(P, R)
    rho[1] = [0.0, 0.0, 0.0, 400.0, 400.0, 400.0]
    with pytest.raises(PredictionError, match="row 2 are outside the workspace"):
        model.poses(rho)
    _, closed = model.solve_poses(rho)
    assert closed.tolist() == [True, False, True]


def test_joints_beyond_their_cone_are_refused():
    robot = ROBOT.model_copy(update={"joint_limit_deg": 20.0})
    model = LegModel(robot)
    home = model.home(1)
    tilted = Rotation.from_euler("x", 35, degrees=True).as_matrix()[None]
    _, plat = model.joint_angles(Poses(home.position, tilted))
    assert plat.max() > 20.0
    with pytest.raises(PredictionError, match=r"poses: row 1 put a joint beyond its range"):
        model.readings(home.position, tilted)
    # Within the cone it serves the pose.
    model.readings(home.position, home.rotation)


def test_a_thermal_model_needs_the_temperature():
    model = LegModel(ROBOT, ("thermal",), np.array([20.0]))
    P, R, T = _poses(3)
    with pytest.raises(PredictionError, match="includes thermal: give the structure temperature"):
        model.readings(P, R)
    model.readings(P, R, temperature=T)


def test_backlash_follows_the_motion_order():
    """The same pose approached from above and from below needs readings β apart."""
    beta = np.full(6, 0.05)
    model = LegModel(ROBOT, ("backlash",), beta)
    home = model.home(1)
    up = home.position + [0.0, 0.0, 10.0]
    seq_p = np.vstack(
        [home.position, up, home.position, home.position - [0, 0, 10.0], home.position]
    )
    seq_r = np.repeat(home.rotation, 5, axis=0)
    rho = model.readings(seq_p, seq_r)
    # Pose 3 comes down to home (legs shortening), pose 5 comes up to it (legs extending).
    assert np.allclose(rho[4] - rho[2], beta, atol=1e-9)
