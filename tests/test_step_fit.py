"""What a clamped step's poses tell (hexcal.procedure.step_fit): the 1σ the guided screen shows
the operator for the leg's points is the spread Monte-Carlo finds for the same poses."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hexcal.acquire.acquisition import RecordedPose
from hexcal.estimate.solvers.direct import type_i_system, type_ii_system
from hexcal.estimate.solvers.linalg import lstsq
from hexcal.procedure.recording import Step
from hexcal.procedure.step_fit import (
    DEFAULT_POSE_NOISE,
    conditioning,
    direction_offset,
    motion_hint,
    pose_noise,
)
from hexcal.vocabulary import Constraint

B = np.array([80.0, 10.0, 0.0])  # platform point, platform frame, mm
A = np.array([120.0, 30.0, -400.0])  # the clamped point (Type II) or the base point (Type I), mm
U = np.array([0.3, 0.1, 1.0]) / np.linalg.norm([0.3, 0.1, 1.0])  # the clamped direction
N_POSES = 12
N_DRAWS = 20000


def poses_of(P: np.ndarray, R: Rotation, rho: np.ndarray, leg: int = 1) -> list[RecordedPose]:
    """Window averages without their raw samples: the step's noise is then the default."""
    readings = np.zeros((len(P), 6))
    readings[:, leg - 1] = rho
    q = R.as_quat(scalar_first=True)
    return [RecordedPose(float(i), P[i], q[i], readings[i], [], []) for i in range(len(P))]


def type_ii(rng: np.random.Generator) -> tuple[np.ndarray, Rotation, np.ndarray]:
    """Poses with the platform point B held at A: P + R B = A."""
    R = Rotation.from_rotvec(rng.uniform(-0.26, 0.26, (N_POSES, 3)))
    return A - R.apply(B), R, np.full(N_POSES, np.linalg.norm(A))


def type_i(rng: np.random.Generator) -> tuple[np.ndarray, Rotation, np.ndarray]:
    """Poses with the leg held along U: P + R B = A + ρ U, ρ the full length."""
    R = Rotation.from_rotvec(rng.uniform(-0.26, 0.26, (N_POSES, 3)))
    rho = rng.uniform(450.0, 600.0, N_POSES)
    return A + rho[:, None] * U - R.apply(B), R, rho


def mc_sigma(system, P, R, rho, rng, sig_p: float, sig_rho: float) -> tuple[float, float]:
    """Largest 1σ of a coordinate of b and of a over N_DRAWS noisy repeats of the poses."""
    Pn = P + rng.normal(0.0, sig_p, (N_DRAWS, *P.shape))
    Rm = np.broadcast_to(R.as_matrix(), (N_DRAWS, *R.as_matrix().shape))
    if system is type_i_system:
        rn = rho + rng.normal(0.0, sig_rho, (N_DRAWS, len(rho)))
        x = lstsq(*type_i_system(Pn, Rm, rn))
    else:
        x = lstsq(*type_ii_system(Pn, Rm))
    sd = x.std(axis=0)
    return float(sd[:3].max()), float(sd[3:6].max())


def test_without_raw_samples_the_step_assumes_the_default_noise():
    P, R, rho = type_ii(np.random.default_rng(1))
    assert pose_noise(poses_of(P, R, rho)) == DEFAULT_POSE_NOISE


#: Four standard errors of a standard deviation estimated from N_DRAWS draws (1/√(2N) each).
MC_TOL = 4 / np.sqrt(2 * N_DRAWS)


@pytest.mark.parametrize(
    "constraint, make, system",
    [
        (Constraint.DIRECTION_LENGTH, type_ii, type_ii_system),
        (Constraint.DIRECTION, type_i, type_i_system),
    ],
    ids=["type-ii", "type-i"],
)
def test_predicted_sigma_is_the_monte_carlo_spread(constraint, make, system):
    """Position and reading noise at the default levels, the orientation term left out
    (platform radius 0). For Type II the prediction is the linear system's exact covariance. For
    Type I the reading noise falls on a row's coordinates along U (σ_ρ u_i) where the prediction
    counts σ_ρ on each: it may be high by up to √(1 + σ_ρ²/σ_p²) (2 % here), never low."""
    rng = np.random.default_rng(7)
    P, R, rho = make(rng)
    step = Step(leg=1, constraint=constraint, n_poses=N_POSES)
    c = conditioning(step, poses_of(P, R, rho), platform_radius_mm=0.0, hint="")
    n = DEFAULT_POSE_NOISE
    sb, sa = mc_sigma(system, P, R, rho, rng, n.position_mm, n.reading_mm)
    assert c.poses == N_POSES and np.isfinite(c.condition)
    high = 1.0
    if constraint == Constraint.DIRECTION:
        high = np.sqrt(1 + (n.reading_mm / n.position_mm) ** 2)
    for predicted, mc in ((c.sigma_b_mm, sb), (c.sigma_a_mm, sa)):
        assert 1 - MC_TOL <= predicted / mc <= high * (1 + MC_TOL), (predicted, mc)


def test_orientation_noise_is_counted_conservatively():
    """Orientation noise σ_θ about each axis moves a row's R b by δθ × R b, whose variance on
    coordinate i is σ_θ² (|b|² − (R b)_i²): between 0 and σ_θ² |b|², which the prediction
    counts (r = |b|). So the prediction is never below the MC spread and at most
    √(1 + σ_θ² r² / σ_p²) above it (4 % here)."""
    rng = np.random.default_rng(3)
    P, R, rho = type_ii(rng)
    step = Step(leg=1, constraint=Constraint.DIRECTION_LENGTH, n_poses=N_POSES)
    r = float(np.linalg.norm(B))
    c = conditioning(step, poses_of(P, R, rho), platform_radius_mm=r, hint="")
    n = DEFAULT_POSE_NOISE
    sig_th = np.deg2rad(n.orientation_deg)
    dth = rng.normal(0.0, sig_th, (N_DRAWS * N_POSES, 3))
    # The tracker reports the rotation off by δθ; the platform point really sits where R puts it.
    Rn = Rotation.from_rotvec(dth) * Rotation.concatenate([R] * N_DRAWS)
    Pn = P + rng.normal(0.0, n.position_mm, (N_DRAWS, *P.shape))
    x = lstsq(*type_ii_system(Pn, Rn.as_matrix().reshape(N_DRAWS, N_POSES, 3, 3)))
    sd = x.std(axis=0)
    high = np.sqrt(1 + (sig_th * r / n.position_mm) ** 2)
    for predicted, mc in ((c.sigma_b_mm, float(sd[:3].max())), (c.sigma_a_mm, float(sd[3:].max()))):
        assert 1 - MC_TOL <= predicted / mc <= high * (1 + MC_TOL), (predicted, mc)


def test_direction_offset_is_the_distance_from_the_fitted_point():
    rng = np.random.default_rng(5)
    P, R, rho = type_ii(rng)
    step = Step(leg=1, constraint=Constraint.DIRECTION_LENGTH, n_poses=N_POSES)
    poses = poses_of(P, R, rho)
    rot = Rotation.from_rotvec([0.1, -0.05, 0.02])
    held = A - rot.apply(B)
    assert direction_offset(step, poses, held, rot, np.nan) == pytest.approx(0.0, abs=1e-9)
    moved = held + np.array([0.0, 0.3, 0.4])
    assert direction_offset(step, poses, moved, rot, np.nan) == pytest.approx(0.5, abs=1e-9)


def test_the_hint_names_the_motion_varied_least():
    rng = np.random.default_rng(2)
    _, R, rho = type_ii(rng)
    rv = R.as_rotvec(degrees=True)
    rv[:, 2] *= 0.05  # hardly any rotation about z
    R = Rotation.from_rotvec(rv, degrees=True)
    step = Step(leg=1, constraint=Constraint.DIRECTION_LENGTH, n_poses=N_POSES)
    assert motion_hint(step, poses_of(A - R.apply(B), R, rho)).startswith(
        "tilt the platform about z"
    )
    assert motion_hint(step, []) == "tilt the platform about the clamped point"
