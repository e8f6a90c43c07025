"""Next best pose: which pose of the clamped leg's constraint manifold to record next.

For the leg being calibrated and its clamp type, feasible candidate poses are drawn on the
manifold (within stroke and joint-angle limits, :class:`~hexcal.model.workspace.Workspace`, and away
from singularities, :data:`MAX_CONDITION`) of the geometry estimated so far; each is scored by
what it adds to the information of the step's constraint (:mod:`hexcal.estimate.bound`): the predicted
E‖â − a‖² (Types I and III) or E‖b̂ − b‖² (Type II) once it is recorded — A-optimality on the
point that matters, computed for every candidate at once with the Woodbury identity. The best
is suggested. Every ``space_filling_every``-th suggestion (every 5th by default) is instead the
candidate farthest from the poses already taken (in position and orientation), so the poses
keep covering the workspace and the diagnosis can still see effects the model does not have.
Suggestions stop when the predicted 1σ of the
point meets the target.

A ridge prior (``prior_mm``, a very loose one) keeps the information invertible before the
step has enough poses to determine its unknowns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.estimate import bound
from hexcal.model.kinematics import condition_number
from hexcal.model.noise import NoiseSigmas
from hexcal.model.robot import Robot
from hexcal.model.workspace import Workspace
from hexcal.vocabulary import Constraint

#: Candidates whose dimensionless leg Jacobian has a larger condition number are dropped: near
#: a singularity the legs do not hold the platform rigidly (about 5 at home, at most 13 over
#: ± 45° tilts and ± 60 mm for the Left Hand robot; 50 is a rotation of 85° about the vertical).
MAX_CONDITION = 50.0
#: Parameters of each clamp type's constraint and which block is "the point that matters".
_POINT = {
    Constraint.DIRECTION: slice(3, 6),
    Constraint.DIRECTION_LENGTH: slice(0, 3),
    Constraint.LENGTH: slice(0, 3),
}


@dataclass
class Suggestion:
    """The pose to record next: ``position`` (3,) mm and ``rotation`` (3, 3); the predicted 1σ
    (mm, RMS over the three coordinates) of the point that matters before and after it;
    ``space_filling``: chosen for coverage, not information; ``done``: the predicted 1σ already
    meets the target, no more poses are needed for it."""

    position: np.ndarray
    rotation: np.ndarray
    sigma_before_mm: float
    sigma_after_mm: float
    space_filling: bool
    done: bool = False


@dataclass
class LegGeometry:
    """What the step's clamp constraint is about: leg ``k`` (0-based), its base and platform
    points (mm) and, for the clamp, the direction (Type I), the clamped point (Type II) or the
    clamped length (Type III)."""

    k: int
    a: np.ndarray
    b: np.ndarray
    direction: np.ndarray | None = None
    point: np.ndarray | None = None
    length: float | None = None


def information(
    constraint: Constraint, geo: LegGeometry, P: np.ndarray, R: np.ndarray, sig: NoiseSigmas
) -> np.ndarray:
    """Information (p, p) of poses P (N, 3), R (N, 3, 3) about the step's unknowns, evaluated
    on the geometry ``geo``."""
    if constraint == Constraint.DIRECTION:
        lengths = np.linalg.norm(P + R @ geo.b - geo.a, axis=-1)
        return bound.information_type_i(P, R, lengths, geo.b, geo.a, geo.direction, sig)
    if constraint == Constraint.DIRECTION_LENGTH:
        return bound.information_type_ii(P, R, geo.b, sig)
    if constraint == Constraint.LENGTH:
        return bound.information_type_iii(P, R, geo.b, geo.a, sig)
    raise ValueError(f"no next-best pose for a '{constraint}' step")


def _rows(constraint, geo, P, R, sig) -> tuple[np.ndarray, np.ndarray]:
    """Per candidate: Jacobian rows J (M, q, p) and noise covariance S (M, q, q) of its
    constraint, so that its information is Jᵀ S⁻¹ J."""
    from hexcal.estimate.solvers.weighted import _point_cov, _tangent_basis

    if constraint == Constraint.LENGTH:
        v = P + R @ geo.b
        d = v - geo.a
        n = d / np.linalg.norm(d, axis=-1, keepdims=True)
        var = (n[:, None, :] @ _point_cov(R, geo.b, sig) @ n[:, :, None])[:, 0, 0]
        J = np.concatenate([-n, -np.ones((len(n), 1))], axis=-1)[:, None, :]
        return J, var[:, None, None]
    cov = _point_cov(R, geo.b, sig)
    eye = np.broadcast_to(np.eye(3), R.shape)
    if constraint == Constraint.DIRECTION_LENGTH:
        return np.concatenate([R, -eye], axis=-1), cov
    u = geo.direction / np.linalg.norm(geo.direction)
    cov = cov + sig.reading_mm**2 * np.outer(u, u)
    e1, e2 = _tangent_basis(u)
    lt = -np.linalg.norm(P + R @ geo.b - geo.a, axis=-1)[:, None, None]
    J = np.concatenate([R, -eye, lt * e1[:, None], lt * e2[:, None]], axis=-1)
    return J, cov


def predicted_sigma_mm(constraint: Constraint, info: np.ndarray) -> float:
    """RMS predicted 1σ (mm) of a coordinate of the point that matters, from the information."""
    cov = np.linalg.inv(info)
    blk = _POINT[constraint]
    return float(np.sqrt(np.trace(cov[blk, blk]) / 3))


def _prior(constraint: Constraint, prior_mm: float) -> np.ndarray:
    p = {Constraint.DIRECTION: 8, Constraint.DIRECTION_LENGTH: 6, Constraint.LENGTH: 4}[constraint]
    return np.eye(p) / prior_mm**2


def candidates(
    sim: Workspace, constraint: Constraint, geo: LegGeometry, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """``n`` feasible poses (P (n, 3), R (n, 3, 3)) on the step's manifold of ``sim``'s robot,
    away from singularities (:data:`MAX_CONDITION`; fewer than ``n`` only if most of the
    manifold is near one)."""

    def draw(m: int):
        if constraint == Constraint.DIRECTION:
            return sim.type_i(geo.k, (m,), rng, direction=geo.direction)
        if constraint == Constraint.DIRECTION_LENGTH:
            return sim.type_ii(geo.k, (m,), rng, point=geo.point)
        return sim.type_iii(geo.k, (m,), rng, length=geo.length, axis=geo.direction)

    P, R = draw(n)
    robot = sim.robot
    for _ in range(20):
        bad = condition_number(robot.a, robot.b, P, Rotation.from_matrix(R)) > MAX_CONDITION
        if not bad.any():
            break
        Pn, Rn = draw(int(bad.sum()))
        P[bad], R[bad] = Pn, Rn
    else:
        keep = condition_number(robot.a, robot.b, P, Rotation.from_matrix(R)) <= MAX_CONDITION
        P, R = P[keep], R[keep]
    return P, R


def suggest(
    constraint: Constraint,
    geo: LegGeometry,
    P_done: np.ndarray,
    R_done: np.ndarray,
    sig: NoiseSigmas,
    sim: Workspace,
    rng: np.random.Generator,
    n_candidates: int = 1000,
    space_filling: bool = False,
    prior_mm: float = 1e3,
    target_mm: float = 0.0,
    score_geo: LegGeometry | None = None,
) -> Suggestion:
    """The next pose (see module docstring). ``P_done`` (N, 3) mm and ``R_done`` (N, 3, 3) are
    the step's poses so far (N may be 0); ``target_mm``: the 1σ at which the step has enough.
    Candidates are drawn on ``geo``'s manifold and scored with ``score_geo`` (default ``geo``):
    tests draw them on the true clamp and score them with what noisy poses estimate."""
    Pc, Rc = candidates(sim, constraint, geo, n_candidates, rng)
    geo = score_geo or geo
    if not len(Pc):
        raise ValueError(
            f"no pose of leg {geo.k + 1}'s {constraint} clamp is away from a singularity within "
            "the motion ranges: check the clamp setting and the robot's geometry"
        )
    M = _prior(constraint, prior_mm)
    if len(P_done):
        M = M + information(constraint, geo, P_done, R_done, sig)
    before = predicted_sigma_mm(constraint, M)
    Minv = np.linalg.inv(M)
    J, S = _rows(constraint, geo, Pc, Rc, sig)
    # Woodbury: (M + Jᵀ S⁻¹ J)⁻¹ = M⁻¹ − M⁻¹ Jᵀ (S + J M⁻¹ Jᵀ)⁻¹ J M⁻¹, per candidate.
    JM = J @ Minv  # (n, q, p)
    inner = np.linalg.inv(S + JM @ np.swapaxes(J, -1, -2))
    after_cov = Minv - np.swapaxes(JM, -1, -2) @ inner @ JM
    blk = _POINT[constraint]
    after = np.sqrt(np.trace(after_cov[:, blk, blk], axis1=-2, axis2=-1) / 3)
    if space_filling and len(P_done):
        i = int(np.argmax(_coverage_distance(Pc, Rc, P_done, R_done)))
    else:
        i = int(np.argmin(after))
    return Suggestion(
        Pc[i],
        Rc[i],
        before,
        float(after[i]),
        space_filling and len(P_done) > 0,
        done=before <= target_mm,
    )


def estimate_geometry(
    constraint: Constraint, k: int, P: np.ndarray, R: np.ndarray, rho: np.ndarray, design: Robot
) -> LegGeometry:
    """The step's clamp and leg k's points (0-based) as its own poses so far estimate them (the
    direct linear forms; at least 4 poses): P (N, 3) mm, R (N, 3, 3), rho (N,) leg k's readings
    mm. What the step cannot tell (a for Type II, b for Type III, the offset for Type I) comes
    from ``design``. Raises ValueError or LinAlgError on a degenerate set."""
    from hexcal.estimate.solvers.direct import sphere_fit, type_i_system, type_ii_system
    from hexcal.estimate.solvers.linalg import lstsq
    from hexcal.estimate.solvers.paper import platform_point_positions

    if constraint == Constraint.DIRECTION:
        x = lstsq(*type_i_system(P, R, rho + design.offsets[k]))
        return LegGeometry(k, x[3:6], x[:3], direction=x[6:] / np.linalg.norm(x[6:]))
    if constraint == Constraint.DIRECTION_LENGTH:
        x = lstsq(*type_ii_system(P, R))
        return LegGeometry(k, design.a[k], x[:3], point=x[3:])
    b = design.b[k]
    a, r = sphere_fit(platform_point_positions(P, R, b))
    v = P[-1] + R[-1] @ b - a
    return LegGeometry(k, a, b, direction=v / np.linalg.norm(v), length=float(r))


def _coverage_distance(Pc, Rc, P_done, R_done) -> np.ndarray:
    """Distance of each candidate to its nearest done pose: mm plus 2 mm per degree."""
    dp = np.linalg.norm(Pc[:, None] - P_done[None], axis=-1)
    cos = (np.einsum("mij,nij->mn", Rc, R_done) - 1.0) / 2.0  # (tr(R_cᵀ R_d) − 1) / 2
    dr = np.rad2deg(np.arccos(np.clip(cos, -1.0, 1.0)))
    return np.min(dp + 2.0 * dr, axis=1)


def _clamp_geometry(robot: Robot, k: int, P: np.ndarray, R: np.ndarray) -> LegGeometry:
    """Leg k's points and the clamp that holds the leg where pose (P (3,) mm, R) puts it."""
    v = P + R @ robot.b[k] - robot.a[k]
    return LegGeometry(
        k,
        robot.a[k],
        robot.b[k],
        direction=v / np.linalg.norm(v),
        point=P + R @ robot.b[k],
        length=float(np.linalg.norm(v)),
    )


def motion_text(
    P_now: np.ndarray, R_now: np.ndarray, P_next: np.ndarray, R_next: np.ndarray
) -> str:
    """The motion from the current pose to the suggested one, as an operator would make it:
    its two largest components, e.g. "tilt the platform about x by +8.2°, move it along z by
    +12 mm"."""
    rv = Rotation.from_matrix(R_next @ R_now.T).as_rotvec(degrees=True)
    dp = P_next - P_now
    parts = [
        (abs(v) / 5.0, f"tilt the platform about {'xyz'[i]} by {v:+.1f}°") for i, v in enumerate(rv)
    ]
    parts += [(abs(v) / 10.0, f"move it along {'xyz'[i]} by {v:+.0f} mm") for i, v in enumerate(dp)]
    parts.sort(key=lambda t: -t[0])
    return ", ".join(t for _, t in parts[:2])
