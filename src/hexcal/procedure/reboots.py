"""A leg's encoder rebooted while recording: the poses after it marked, its reading checked.

The CAN driver counts each node's reboots (a boot-up while running) and every reading set
carries the counts (:attr:`hexcal.acquire.acquisition.LegSample.reboots`). An encoder that
keeps no preset (an incremental one, a lost battery) comes back reading off by its lost zero,
and sets it up again does not restore that. So at the first pose recorded after a reboot, the
leg's reading is compared with its prediction from the tracker's pose and the model (the
session's latest calibrated model, else the drawing): the difference at that pose, less its
median over the poses before, is the jump; the scatter of that difference over the poses before
(the model's own error from pose to pose, and the noise) is what it must exceed,
:data:`JUMP_K` times. A jump beyond it is marked at once, on the pose and in the session
(:class:`~hexcal.procedure.session_model.EncoderReboot`); the diagnosis tests a zero step
there first (:mod:`hexcal.diagnosis.reboot`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from hexcal.acquire.acquisition import RecordedPose
from hexcal.estimate.predict import LegModel
from hexcal.procedure.session_model import EncoderReboot, PoseRecord, Session

#: The jump must exceed this many times the scatter of reading − prediction before the reboot.
JUMP_K = 5.0
#: The poses before the reboot the scatter is taken over (the latest), and the fewest judged on.
BEFORE_POSES = 20
MIN_BEFORE = 3


def reboot_counts(pose: RecordedPose) -> tuple[int, ...]:
    """Each leg's reboots as the pose's last reading set tells (empty: the source tells none)."""
    counts = [s.reboots for s in pose.leg_samples if s.reboots]
    if not counts:
        return ()
    return tuple(int(v) for v in np.max(np.array(counts), axis=0))


def _model(session: Session) -> LegModel:
    """The session's latest calibrated model, else its drawing."""
    from hexcal.estimate.model_file import leg_model_of

    for res in reversed(session.results):
        if res.calibrated is not None:
            return leg_model_of(res.calibrated)
    return LegModel(session.robot)


def _residual(model: LegModel, records: Sequence[PoseRecord], leg: int) -> np.ndarray:
    """(N,) mm: leg ``leg``'s reading less its prediction at each pose."""
    from scipy.spatial.transform import Rotation

    P = np.array([r.position for r in records], float)
    R = Rotation.from_quat(np.array([r.quaternion for r in records], float), scalar_first=True)
    predicted = model.readings(P, R.as_matrix(), check_limits=False)
    return np.array([r.readings[leg - 1] for r in records], float) - predicted[:, leg - 1]


def check_reboot(session: Session, record: PoseRecord, leg: int, sigma_mm: float) -> EncoderReboot:
    """The reboot of leg ``leg`` before ``record`` (the first pose after it, not yet in
    ``session``), its reading judged against the poses before (module docstring); ``sigma_mm``
    is the reading's noise at the pose (its still window's spread)."""
    before = session.poses[-BEFORE_POSES:]
    if len(before) < MIN_BEFORE:
        return EncoderReboot(leg=leg, pose_id=record.pose_id)
    res = _residual(_model(session), [*before, record], leg)
    prior, now = res[:-1], float(res[-1])
    jump = now - float(np.median(prior))
    threshold = JUMP_K * max(float(np.std(prior, ddof=1)), sigma_mm)
    return EncoderReboot(
        leg=leg,
        pose_id=record.pose_id,
        jump_mm=round(jump, 6),
        threshold_mm=round(threshold, 6),
        beyond=abs(jump) > threshold,
    )


def reboot_note(r: EncoderReboot) -> str:
    """The operator's sentence for a reboot, put on the pose."""
    head = f"leg {r.leg}'s encoder rebooted before this pose (pose {r.pose_id})"
    if r.jump_mm is None:
        return f"{head}: too few poses before it to check its zero; the diagnosis tests it"
    if r.beyond:
        return (
            f"{head} and came back {r.jump_mm:+.2f} mm off against the tracker's pose and the "
            f"model (beyond {r.threshold_mm:.3f} mm): check its zero (re-home, or restore its "
            "preset)"
        )
    return f"{head}; its reading agrees with the tracker's pose and the model (jump {r.jump_mm:+.3f} mm)"
