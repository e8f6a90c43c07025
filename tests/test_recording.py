"""Recording a procedure: clamp checks, nothing lost, and a scripted session through the real
drivers from mock hardware that calibrates to the simulator's truth within its uncertainty."""

import re

import numpy as np
import pytest
from scipy import stats
from scipy.spatial.transform import Rotation

from hexcal.acquire.acquisition import LegSample, RecordedPose, StillWindow, TrackerSample
from hexcal.acquire.live import open_rig
from hexcal.estimate.calibrate import calibrate
from hexcal.mock_hw.motion import MockMotionController
from hexcal.mock_hw.rig import mock_rig
from hexcal.mock_hw.robot import MockRobot
from hexcal.procedure.recording import (
    ClampSlipped,
    NoiseLevels,
    RunSettings,
    Step,
    StepRecorder,
    reclamped_at_home,
    record_procedure,
    standard_procedure,
    still_window_noise,
)
from hexcal.sim.session_sim import SessionPlan, perturbed_truth

SIG_P, SIG_DEG, SIG_R = 0.01, 0.002, 0.002  # per sample, as the mock robot's default noise


def fake_pose(robot: MockRobot, rng, n=20) -> RecordedPose:
    """A recorded pose of n samples drawn from the mock robot at its current pose."""
    ts, ls = [], []
    for i in range(n):
        p, q, rms = robot.tracker_sample()
        ts.append(TrackerSample(i * 0.01, p, q, rms))
        ls.append(LegSample(i * 0.01, robot.encoder_readings()))
    P = np.mean([s.position for s in ts], axis=0)
    q = Rotation.from_quat([s.quaternion for s in ts], scalar_first=True).mean()
    return RecordedPose(
        n * 0.01,
        P,
        q.as_quat(scalar_first=True),
        np.mean([s.readings for s in ls], axis=0),
        ts,
        ls,
    )


@pytest.fixture
def rig_parts(design):
    truth = perturbed_truth(design, np.random.default_rng(11), SessionPlan())
    robot = MockRobot(truth, seed=11)
    return truth, robot, MockMotionController(robot, seed=11)


def test_standard_procedure_order():
    steps = standard_procedure(2, 3, 4, 5)
    assert [s.name for s in steps[:3]] == ["leg1-direction", "leg1-direction+length", "leg1-length"]
    assert len(steps) == 19 and steps[-1] == Step(0, "free", 5)
    assert [s.n_poses for s in steps[:3]] == [2, 3, 4]
    assert all(s.leg != 0 for s in standard_procedure(n_free=0))


def test_still_window_noise_recovers_the_per_sample_sigmas(rig_parts):
    _, robot, ctl = rig_parts
    rng = np.random.default_rng(0)
    poses = []
    for _ in range(40):
        ctl.next_pose()
        poses.append(fake_pose(robot, rng))
    lv = still_window_noise(poses)
    # A σ pooled over dof degrees of freedom (40 windows × 19 × 3 axes, or × 6 legs) has a
    # relative standard error of 1/√(2·dof) (χ²): within 4 of it (6 % and 4.2 %).
    dof3, dof6 = 40 * 19 * 3, 40 * 19 * 6
    assert lv.position_mm == pytest.approx(SIG_P, rel=4 / np.sqrt(2 * dof3))
    assert lv.orientation_deg == pytest.approx(SIG_DEG, rel=4 / np.sqrt(2 * dof3))
    assert lv.reading_mm == pytest.approx(SIG_R, rel=4 / np.sqrt(2 * dof6))


def test_a_slipping_length_clamp_refuses_the_pose(rig_parts):
    _, robot, ctl = rig_parts
    rng = np.random.default_rng(1)
    rec = StepRecorder(Step(2, "length", 8), clamp_tolerance_mm=0.02)
    ctl.clamp(2, "length")
    for _ in range(3):  # holds: accepted
        ctl.next_pose()
        rec.accept(fake_pose(robot, rng))
    ctl.slip(mm_per_move=0.05)
    ctl.next_pose()
    with pytest.raises(
        ClampSlipped, match=r"leg 2 is clamped in length but its encoder moved \+0\.0\d+ mm"
    ) as caught:
        rec.accept(fake_pose(robot, rng))
    # The slip (0.05 mm), within the reading noise of two poses' means (σ a few µm).
    moved = float(re.search(r"moved \+(\d\.\d+) mm", str(caught.value)).group(1))
    assert moved == pytest.approx(0.05, abs=0.003)
    assert len(rec.poses) == 3


@pytest.mark.parametrize(
    "constraint, slip, what",
    [
        ("direction", {"deg_per_move": 0.05}, "one clamped direction"),
        ("direction+length", {"mm_per_move": 0.05}, "one clamped point"),
    ],
)
def test_a_slipping_direction_clamp_fails_the_step_check(rig_parts, constraint, slip, what):
    truth, robot, ctl = rig_parts
    rng = np.random.default_rng(2)
    noise = NoiseLevels(SIG_P / np.sqrt(20), SIG_DEG / np.sqrt(20), SIG_R / np.sqrt(20))
    radius = float(np.linalg.norm(truth.b[2]))
    for slipping in (False, True):
        rec = StepRecorder(Step(3, constraint, 8))
        ctl.clamp(3, constraint)
        if slipping:
            ctl.slip(**slip)
        for _ in range(8):
            ctl.next_pose()
            rec.accept(fake_pose(robot, rng))
        ctl.release()
        check = rec.finish(noise, radius)
        if not slipping:  # a holding clamp fits its model to the noise
            assert check.ok and check.rms_mm < 3 * check.expected_mm, check
        else:
            assert not check.ok
            assert re.search(
                f"leg3-{re.escape(constraint)}: the poses do not fit {what}", check.message
            )


def window():
    """A short still window (enough frames at 60 Hz and SYNC sets at 100 Hz to average), with
    the default motion and fault limits."""
    return StillWindow(duration_s=0.2)


def test_slips_on_the_mock_rig_are_caught_and_nothing_is_lost(design):
    """Through the real drivers: each step's first clamp slips; the step is set aside with its
    poses and the reason, repeated, and the repeat is accepted."""
    truth = perturbed_truth(design, np.random.default_rng(12), SessionPlan())
    steps = [Step(2, "length", 4), Step(5, "direction", 5)]
    slips = {"length": {"mm_per_move": 0.1}, "direction": {"deg_per_move": 0.1}}
    events = []
    with mock_rig(truth, seed=12) as rig, open_rig(rig.config, window()) as live:

        def on_clamp(step, attempt):
            if attempt == 0:
                rig.motion.slip(**slips[step.constraint])

        session = record_procedure(
            live.acquisition,
            rig.motion,
            steps,
            float(np.linalg.norm(truth.b).max()),
            on_event=events.append,
            on_clamp=on_clamp,
        )
    assert [a.step for a in session.accepted] == [steps[0]] * 4 + [steps[1]] * 5
    slipped = [r for r in session.rejected if "slipping" in r.reason]
    misfit = [r for r in session.rejected if "do not fit one clamped direction" in r.reason]
    assert slipped and misfit, [r.reason for r in session.rejected]
    assert len(misfit) == 5 and all(r.pose is not None for r in misfit)  # kept, with the reason
    assert any("re-tighten it and repeat this step" in e for e in events)


@pytest.mark.slow
def test_scripted_session_through_the_drivers_calibrates_to_the_truth(design):
    """All six legs' procedures recorded from mock hardware through the NDI driver (BX over
    ndimock://), the CANopen driver (virtual bus) and the acquisition; Model 42 then lands on
    the simulator's truth within the uncertainty it reports (Mahalanobis distance against the
    χ² distribution of 42 parameters)."""
    truth = perturbed_truth(design, np.random.default_rng(21), SessionPlan())
    with mock_rig(truth, seed=21) as rig, open_rig(rig.config, window()) as live:
        session = record_procedure(
            live.acquisition,
            rig.motion,
            standard_procedure(4, 4, 4, 12),
            float(np.linalg.norm(truth.b, axis=1).max()),
            RunSettings(settle_s=0.03),
        )
    assert len(session.accepted) == 6 * 12 + 12
    meas = session.measurements()
    assert list(meas.step[:4]) == ["leg1-direction"] * 4
    inst = session.instruments()
    # The still windows see the mock's per-sample noise: a σ pooled over dof degrees of freedom
    # has a relative standard error of 1/√(2·dof) (≈ 1.3 % over 84 windows of 12 frames);
    # within 4 of it.
    n = [len(a.pose.good_tracker_samples) for a in session.accepted]
    dof = sum(3 * (k - 1) for k in n)
    per_sample = inst.tracker.position_sigma_mm * np.sqrt(np.mean(n))
    assert per_sample == pytest.approx(SIG_P, rel=4 / np.sqrt(2 * dof)), (per_sample, dof)
    cal = calibrate(meas, design, 42, inst)
    ref = cal.refinement
    assert ref.status == ["ok"] * 42
    # the noise the windows measured explains the residual: χ² within its distribution's upper
    # 1e-3 tail (3.1σ, one-sided; σ of χ²/dof is √(2/dof))
    assert stats.chi2.sf(ref.chi2, ref.dof) > 1e-3 and ref.chi2 / ref.dof < 1.5
    true = {f"a{k + 1}.{c}": truth.a[k, j] for k in range(6) for j, c in enumerate("xyz")}
    true |= {f"b{k + 1}.{c}": truth.b[k, j] for k in range(6) for j, c in enumerate("xyz")}
    true |= {f"offset{k + 1}": truth.offsets[k] for k in range(6)}
    err = ref.x - np.array([true[n] for n in ref.names])
    d2 = float(err @ np.linalg.solve(ref.cov, err))
    assert d2 < stats.chi2.ppf(0.999, 42), (d2, np.abs(err / ref.sigma).max())
    # and the error is far below the build tolerance the linear methods started from
    assert np.abs(err).max() < 0.1


def test_a_fresh_clamp_that_allows_no_pose_is_set_again_at_home(truth, far_type_ii_clamp):
    """A scripted run whose leg was clamped with the platform far out, where its Type II clamp
    allows no pose within the limits: the clamp is released, the platform goes home, the leg
    is clamped there and the step is recorded and accepted, as the text UI's operator does."""
    from hexcal.mock_hw.instant import InstantAcquisition

    robot = MockRobot(truth, seed=5)
    mover = MockMotionController(robot, seed=5)
    leg, P, R = far_type_ii_clamp(mover.sim, truth)
    step = Step(leg, "direction+length", 5)

    def clamp_far_out(step, attempt):
        mover.release()
        mover.move_to(P, R)
        mover.clamp(step.leg, step.constraint)

    events: list[str] = []
    session = record_procedure(
        InstantAcquisition(robot, window()),
        mover,
        [step],
        float(np.linalg.norm(truth.b, axis=1).max()),
        RunSettings(settle_s=0.0),
        on_event=events.append,
        on_clamp=clamp_far_out,
    )
    assert reclamped_at_home(step) in events
    assert len(session.accepted) == 5 and not session.rejected
    P_home = np.asarray(truth.home.position)
    R_home = Rotation.from_quat(truth.home.quaternion, scalar_first=True).as_matrix()
    point = (
        session.accepted[0].pose.position
        + Rotation.from_quat(session.accepted[0].pose.quaternion, scalar_first=True).as_matrix()
        @ truth.b[leg - 1]
    )
    # the clamped point is where it was at home (within the tracker's noise), not far out
    assert np.linalg.norm(point - (P_home + R_home @ truth.b[leg - 1])) < 0.5
    assert np.linalg.norm(point - (P + R @ truth.b[leg - 1])) > 10
