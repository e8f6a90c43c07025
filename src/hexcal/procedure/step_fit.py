"""What one clamped step's poses so far tell, computed from one snapshot of them: the pose noise
of their still windows, how well they determine the clamped leg's points (:func:`conditioning`),
how far a live pose lies from the line or point they fit (:func:`direction_offset`), the motion
they have varied least (:func:`motion_hint`) and the next best pose (:func:`suggest`).

Every function takes the poses as a list the caller copied once (``GuidedSession._poses``): the
text UI's recording worker appends to the step's list from its thread, and whatever is computed
at once (positions, rotations, readings, noise) must count the same poses.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.acquire.acquisition import RecordedPose
from hexcal.estimate import nbp
from hexcal.estimate.solvers.direct import type_i_system, type_ii_system
from hexcal.estimate.solvers.linalg import lstsq
from hexcal.estimate.solvers.paper import platform_point_positions
from hexcal.model.noise import NoiseSigmas
from hexcal.model.robot import Robot
from hexcal.model.workspace import Workspace
from hexcal.procedure.recording import NoiseLevels, Step, per_pose_noise, still_window_noise
from hexcal.vocabulary import Constraint

#: Noise assumed for the live predictions until the step's own still windows tell (1σ of a
#: recorded pose): a good optical tracker and encoder, averaged over a still window.
DEFAULT_POSE_NOISE = NoiseLevels(0.003, 0.0006, 0.0006)

#: What a pose of each constraint can vary, for the motion hint: rotations (about x, y, z) and
#: translations (along x, y, z). A clamped point leaves only rotations.
_HINT_DOFS = {
    Constraint.DIRECTION_LENGTH: (0, 1, 2),
    Constraint.DIRECTION: (0, 1, 2, 3, 4, 5),
    Constraint.LENGTH: (0, 1, 2, 3, 4, 5),
    Constraint.FREE: (0, 1, 2, 3, 4, 5),
}
#: The least offset from the step's fit the live monitor calls a moved clamp, mm: below it a
#: clamp's give is within what a lab's fixtures hold anyway.
MIN_CLAMP_MOVE_MM = 0.03
#: Poses a clamped step needs before its geometry is estimated and a next best pose suggested.
NBP_MIN_POSES = 4
#: How far an operator can typically vary each: deg for rotations, mm for translations.
_HINT_SCALE = np.array([15.0, 15.0, 15.0, 30.0, 30.0, 30.0])


@dataclass
class Conditioning:
    """How well the step's poses determine the leg: ``sigma_b_mm`` and ``sigma_a_mm`` (largest
    predicted 1σ of a coordinate of the platform point and of the base point or clamped point;
    NaN when not yet determined), the scaled system's condition number, the pose-noise the
    prediction used, and ``hint``: the motion that the poses have varied least."""

    poses: int
    sigma_b_mm: float
    sigma_a_mm: float
    condition: float
    hint: str


def _window_noise(
    poses: Sequence[RecordedPose], levels: Callable[[list[RecordedPose]], NoiseLevels]
) -> NoiseLevels:
    """``levels`` of the poses' still windows; :data:`DEFAULT_POSE_NOISE` until two poses with
    their raw samples tell."""
    if len(poses) >= 2 and all(p.tracker_samples and p.leg_samples for p in poses):
        try:
            n = levels(list(poses))
            if np.isfinite([n.position_mm, n.orientation_deg, n.reading_mm]).all():
                return n
        except (ValueError, ZeroDivisionError):
            pass
    return DEFAULT_POSE_NOISE


def pose_noise(poses: Sequence[RecordedPose]) -> NoiseLevels:
    """1σ of a recorded pose (a still window's mean) from the poses' windows."""
    return _window_noise(poses, per_pose_noise)


def sample_noise(poses: Sequence[RecordedPose]) -> NoiseLevels:
    """1σ of ONE sample of each stream (what the live display shows), from the scatter inside
    the poses' still windows (until they tell, the monitor's floor, :data:`MIN_CLAMP_MOVE_MM`,
    rules)."""
    return _window_noise(poses, still_window_noise)


def live_offset_limit_mm(
    step: Step, poses: Sequence[RecordedPose], platform_radius_mm: float
) -> float:
    """How far (mm) a live pose may lie from the line or point the step's poses fit before the
    monitor asks whether the clamp moved: 4σ of one live sample — the live pose is a single
    sample, not a window's mean, so its noise is the samples' (:func:`sample_noise`), √(samples
    per window) times a recorded pose's — and at least :data:`MIN_CLAMP_MOVE_MM`. A 3-D offset
    of per-coordinate σ passes 4σ in 0.1 % of samples; against a recorded pose's σ a held
    clamp was called moved in 3.5 % of them."""
    n = sample_noise(poses)
    var = (
        n.position_mm**2
        + (np.deg2rad(n.orientation_deg) * platform_radius_mm) ** 2
        + (n.reading_mm**2 if step.constraint == Constraint.DIRECTION else 0.0)
    )
    return max(4.0 * float(np.sqrt(var)), MIN_CLAMP_MOVE_MM)


def step_arrays(
    step: Step, poses: Sequence[RecordedPose]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """P (n, 3) mm, R (n, 3, 3), and the clamped leg's readings (n,) mm of ``poses``."""
    if not step.leg:
        raise ValueError(f"{step.name} clamps no leg: its poses make no leg's system")
    P = np.array([p.position for p in poses])
    R = Rotation.from_quat(np.array([p.quaternion for p in poses]), scalar_first=True)
    rho = np.array([p.readings[step.leg - 1] for p in poses])
    return P, R.as_matrix(), rho


def direction_offset(
    step: Step, poses: Sequence[RecordedPose], pos: np.ndarray, rot: Rotation, reading: float
) -> float:
    """How far (mm) the live pose (``pos`` (3,) mm, ``rot``, the clamped leg's ``reading`` mm)
    lies from the line (Type I) or point (Type II) that the step's poses fit."""
    P, R, rho = step_arrays(step, poses)
    Rl = rot.as_matrix()
    if step.constraint == Constraint.DIRECTION:
        x = lstsq(*type_i_system(P, R, rho))
        b, a, u = x[:3], x[3:6], x[6:]
        if not np.isfinite(reading):
            return float("nan")
        return float(np.linalg.norm(pos + Rl @ b - a - reading * u))
    x = lstsq(*type_ii_system(P, R))
    return float(np.linalg.norm(pos + Rl @ x[:3] - x[3:]))


def conditioning(
    step: Step,
    poses: Sequence[RecordedPose],
    platform_radius_mm: float,
    hint: str,
    design_b: np.ndarray | None = None,
) -> Conditioning:
    """The predicted uncertainty of the step's linear system on ``poses``: the 1σ of the leg's
    points from the system's normal matrix and the poses' noise, and its condition number.

    ``platform_radius_mm``: |b_k| of the design, to scale orientation noise into mm. ``hint``:
    carried into the result. ``design_b`` (6, 3) mm: the platform points to use for a length
    step's sphere fit (the previous direction+length step's result is not known here; the
    design is close enough for a prediction)."""
    n = len(poses)
    nan = float("nan")
    if not step.leg or n == 0:
        return Conditioning(n, nan, nan, nan, hint)
    P, R, rho = step_arrays(step, poses)
    noise = pose_noise(poses)
    sig_row = np.sqrt(
        noise.position_mm**2
        + (np.deg2rad(noise.orientation_deg) * platform_radius_mm) ** 2
        + (noise.reading_mm**2 if step.constraint == Constraint.DIRECTION else 0.0)
    )
    groups: tuple[slice | None, slice]
    if step.constraint == Constraint.DIRECTION:
        A, _ = type_i_system(P, R, rho)
        groups = (slice(0, 3), slice(3, 6))
    elif step.constraint == Constraint.DIRECTION_LENGTH:
        A, _ = type_ii_system(P, R)
        groups = (slice(0, 3), slice(3, 6))
    else:
        b = np.zeros(3) if design_b is None else np.asarray(design_b)[step.leg - 1]
        V = platform_point_positions(P, R, b)
        w = V - V.mean(axis=0)
        # Sphere fit rows 2 (V − V̄)·a + c = |V − V̄|²: a row's noise is 2 |V − V̄| σ.
        A = np.concatenate([2.0 * w, np.ones((n, 1))], axis=1)
        sig_row = 2.0 * float(np.linalg.norm(w, axis=1).mean()) * sig_row
        groups = (None, slice(0, 3))
    if A.shape[0] < A.shape[1]:
        return Conditioning(n, nan, nan, float("inf"), hint)
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    s = np.linalg.svd(A / scale, compute_uv=False)
    cond = float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
    if A.shape[0] == A.shape[1] or not np.isfinite(cond) or cond > 1e12:
        return Conditioning(n, nan, nan, cond, hint)
    cov = sig_row**2 * np.linalg.pinv((A / scale).T @ (A / scale)) / np.outer(scale, scale)
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    sb = nan if groups[0] is None else float(sd[groups[0]].max())
    sa = float(sd[groups[1]].max())
    return Conditioning(n, sb, sa, cond, hint)


def motion_hint(step: Step, poses: Sequence[RecordedPose]) -> str:
    """The motion ``poses`` have varied least, relative to what an operator can (a step at
    home or of a pattern has its own words: the caller's)."""
    if len(poses) < 2:
        return {
            Constraint.DIRECTION_LENGTH: "tilt the platform about the clamped point",
            Constraint.DIRECTION: "move the platform along and about the clamped leg",
            Constraint.LENGTH: "swing the clamped leg to the sides, forwards and back",
            Constraint.FREE: "spread the poses over the workspace",
        }[step.constraint]
    rv = Rotation.from_quat(np.array([p.quaternion for p in poses]), scalar_first=True).as_rotvec(
        degrees=True
    )
    P = np.array([p.position for p in poses])
    span = np.concatenate([np.ptp(rv, axis=0), np.ptp(P, axis=0)]) / _HINT_SCALE
    dofs = _HINT_DOFS[step.constraint]
    d = min(dofs, key=lambda i: span[i])
    axis = "xyz"[d % 3]
    half = span[d] * _HINT_SCALE[d] / 2
    if d < 3:
        return f"tilt the platform about {axis} (its poses span only ±{half:.1f}° so far)"
    return f"move the platform along {axis} (its poses span only ±{half:.1f} mm so far)"


def suggest(
    step: Step, poses: Sequence[RecordedPose], design: Robot, n_candidates: int
) -> nbp.Suggestion | None:
    """The next best pose of a clamped step on the geometry ``poses`` estimate (None before
    :data:`NBP_MIN_POSES`, on a free step, or when the fit is degenerate). Every 5th is a
    space-filling one; seeded by the pose count, so the same poses give the same suggestion."""
    n = len(poses)
    if not step.leg or n < NBP_MIN_POSES:
        return None
    k = step.leg - 1
    P, R, rho = step_arrays(step, poses)
    noise = pose_noise(poses)
    sig = NoiseSigmas(noise.position_mm, np.deg2rad(noise.orientation_deg), noise.reading_mm)
    try:
        geo = nbp.estimate_geometry(step.constraint, k, P, R, rho, design)
        a_all, b_all = design.a.copy(), design.b.copy()
        a_all[k], b_all[k] = geo.a, geo.b
        sim = Workspace(design.with_geometry(a_all, b_all, design.offsets))
        return nbp.suggest(
            step.constraint,
            geo,
            P,
            R,
            sig,
            sim,
            np.random.default_rng(n),
            n_candidates=n_candidates,
            space_filling=n % 5 == 4,
            target_mm=step.target_sigma_mm or 0.0,
        )
    except (ValueError, np.linalg.LinAlgError, RuntimeError):
        return None  # a degenerate fit or no feasible candidate: no suggestion this time
