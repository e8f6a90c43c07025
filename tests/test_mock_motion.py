"""The mock motion controller: clamps constrain the true robot; a slipping clamp creeps."""

import numpy as np
import pytest

from hexcal.mock_hw.motion import CLAMPS, MockMotionController, MotionError
from hexcal.mock_hw.robot import MockRobot
from hexcal.sim.session_sim import SessionPlan, perturbed_truth


@pytest.fixture
def controller(design):
    truth = perturbed_truth(design, np.random.default_rng(5), SessionPlan())
    return MockMotionController(MockRobot(truth, seed=5), seed=5)


def leg(ctl, k):
    """Leg k (1..6) at the robot's true pose: direction, length mm, B_k mm."""
    P, R = ctl.robot.true_pose()
    point = P + R @ ctl.robot.truth.b[k - 1]
    v = point - ctl.robot.truth.a[k - 1]
    return v / np.linalg.norm(v), np.linalg.norm(v), point


@pytest.mark.parametrize("constraint", CLAMPS)
def test_clamped_moves_keep_the_constraint_on_the_true_geometry(controller, constraint):
    u0, l0, c0 = leg(controller, 3)
    controller.clamp(3, constraint)
    lengths, dirs, points, other = [], [], [], []
    for _ in range(10):
        controller.next_pose()
        u, length, c = leg(controller, 3)
        lengths.append(length), dirs.append(u), points.append(c)
        other.append(leg(controller, 1)[1])
    lengths, dirs, points = np.array(lengths), np.array(dirs), np.array(points)
    if "direction" in constraint:
        assert np.allclose(dirs, u0, atol=1e-9)
    if "length" in constraint:
        assert np.allclose(lengths, l0, atol=1e-9)
    if constraint == "direction+length":
        assert np.allclose(points, c0, atol=1e-9)
    # ...and the motion is real: what is not clamped varies.
    if constraint == "direction":
        assert np.ptp(lengths) > 5.0
    if constraint == "length":
        assert np.degrees(np.arccos(np.clip(dirs @ u0, -1, 1))).max() > 2.0
    assert np.ptp(other) > 1.0  # the unclamped legs move in every case
    controller.release()
    P1 = controller.robot.true_pose()[0]
    controller.next_pose()
    assert not np.allclose(controller.robot.true_pose()[0], P1)


def test_move_against_the_clamp_is_refused(controller):
    controller.clamp(2, "length")
    P, R = controller.robot.true_pose()
    with pytest.raises(MotionError, match=r"leg 2 is clamped \(length\): that pose would move it"):
        controller.move_to(P + [0.0, 0.0, 5.0], R)
    controller.release()
    controller.move_to(P + [0.0, 0.0, 5.0], R)
    assert np.allclose(controller.robot.true_pose()[0], P + [0, 0, 5])


def test_one_clamp_at_a_time_and_bad_requests(controller):
    controller.clamp(1, "direction")
    with pytest.raises(MotionError, match="leg 1 is still clamped"):
        controller.clamp(2, "length")
    controller.release()
    with pytest.raises(MotionError, match="unknown clamp"):
        controller.clamp(2, "angle")
    with pytest.raises(MotionError, match=r"legs are 1\.\.6"):
        controller.clamp(7, "length")
    with pytest.raises(MotionError, match="nothing can slip"):
        controller.slip(mm_per_move=0.1)


@pytest.mark.parametrize(
    "constraint, kwargs",
    [
        ("length", {"mm_per_move": 0.05}),
        ("direction", {"deg_per_move": 0.1}),
        ("direction+length", {"mm_per_move": 0.05}),
    ],
)
def test_a_slipping_clamp_creeps_by_the_set_amount_per_move(controller, constraint, kwargs):
    u0, l0, c0 = leg(controller, 4)
    controller.clamp(4, constraint)
    controller.slip(**kwargs)
    n = 6
    for _ in range(n):
        controller.next_pose()
    u, length, c = leg(controller, 4)
    if constraint == "length":
        assert length - l0 == pytest.approx(n * 0.05, abs=1e-9)
    elif constraint == "direction":
        assert np.degrees(np.arccos(u @ u0)) == pytest.approx(n * 0.1, abs=1e-6)
    else:
        assert np.linalg.norm(c - c0) == pytest.approx(n * 0.05, abs=1e-9)
    controller.release()  # a release ends the slip; a new clamp holds
    controller.clamp(4, constraint)
    u1, l1, _ = leg(controller, 4)
    controller.next_pose()
    u2, l2, _ = leg(controller, 4)
    if "length" in constraint:
        assert l2 == pytest.approx(l1, abs=1e-9)
    if "direction" in constraint:
        assert np.allclose(u2, u1, atol=1e-9)


def test_a_clamp_no_pose_can_satisfy_is_a_motion_error_not_a_crash(controller):
    """Clamped (direction and length) where the leg's point sits at the edge of the workspace,
    no rotation about it keeps the six legs within their limits: the controller says so as a
    MotionError (the text UI shows it and the mock operator stops), it does not raise an
    internal error. The point is the one the seed-7 rig reached in the text UI's auto mode."""
    from dataclasses import replace

    controller.clamp(2, "direction+length")
    c = controller.clamp_state
    far = c.point + np.array([0.0, -150.0, -80.0])  # far out: past the joints' limits
    controller.clamp_state = replace(c, point=far)
    with pytest.raises(MotionError, match="release the clamp, move the platform nearer home"):
        controller.next_pose()
