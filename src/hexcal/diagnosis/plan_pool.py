"""The poses a plan picks from (:mod:`hexcal.diagnosis.plan`): random reachable free poses
within the session's box and tilt about home (the random poses a plan is compared with are drawn
from these alone), and as many on that region's edge, where an optimal design's poses sit.

Reachable (:func:`reachable`): within the legs' strokes ``leg_range_mm``, the joints' limits
``joint_limit_deg``, and away from singularities as :mod:`hexcal.estimate.nbp` keeps them.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.estimate.effect_fit import Problem
from hexcal.estimate.nbp import MAX_CONDITION
from hexcal.estimate.predict import LegModel
from hexcal.io.measurements import Measurements
from hexcal.model.kinematics import condition_number
from hexcal.model.robot import Robot
from hexcal.model.workspace import Limits, PoseRanges, Workspace

#: The plan's poses range over this many times the session's box and tilt about home (within
#: the strokes and the joints' limits). Twice gave the plan more separation (gain against
#: compliance, 20 poses: 2.6–3.2 times 20 random ones' where the session's own span gave
#: 1.7–2.3) but random poses from the wider set nearly as much: over 30 sessions random poses
#: named the right one in 77 % for ujoint against the geometry (32 % within the session's span),
#: 68 % for gain against compliance. The session's span it is.
REACH = 1.0
#: Rounds of random draws the candidate poses are collected over.
ROUNDS = 25
#: Poses drawn per round: at least this many, and twice those asked for.
BATCH = 200


def _candidates(
    problem: Problem, robot: Robot, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``n`` reachable free poses (P (K, 3) mm, R (K, 3, 3)), uniform over those within
    :data:`REACH` times the session's box and tilt about home (:func:`session_ranges`), the
    strokes and the joints' limits, away from singularities (:func:`reachable`): drawn in
    rounds, the unreachable ones dropped, then nearer home (the session's span, half of it ...)
    while fewer than ``n`` are found, so that a workspace the limits cut deep gives what it
    has."""
    span = session_ranges(problem.meas, robot)
    ws = Workspace(robot)
    Ps, Rs, found = [], [], 0
    for reach in dict.fromkeys((REACH, 1.0, 0.5, 0.25)):  # limits that cut deep: nearer home
        box, tilt = reach * np.asarray(span.box_mm), np.deg2rad(reach * span.tilt_deg)
        for _ in range(ROUNDS):
            k = max(2 * n, BATCH)
            P = ws.home_position + rng.uniform(-1.0, 1.0, (k, 3)) * box
            R = Rotation.from_rotvec(rng.uniform(-tilt, tilt, (k, 3))).as_matrix()
            R = R @ ws.home_rotation
            ok = reachable(robot, P, R)
            Ps.append(P[ok])
            Rs.append(R[ok])
            found += int(ok.sum())
            if found >= n:
                break
        if found >= n:
            break
    if found == 0:
        raise ValueError(
            "plan: no free pose within the session's range is reachable: check leg_range_mm and "
            "joint_limit_deg in robot.json"
        )
    return np.concatenate(Ps)[:n], np.concatenate(Rs)[:n]


#: Scales (of the session's box and tilt about home) a boundary candidate is tried at along
#: its direction, the largest reachable kept.
EDGE_SCALES = (1.0, 0.85, 0.7, 0.55, 0.4)


def _edge_candidates(
    problem: Problem, robot: Robot, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``n`` reachable free poses on the edge of what the session spans: an optimal
    design's poses sit on the boundary of the region it may use (a contribution linear or
    quadratic in the pose is largest there), which uniform draws reach rarely in six
    dimensions. Half are corners of the session's box and tilt (every coordinate at ±1 of its
    span), half on its faces (one coordinate at ±1, the rest uniform); each is pulled in
    towards home (:data:`EDGE_SCALES`) until reachable (:func:`reachable`), dropped if never."""
    span = session_ranges(problem.meas, robot)
    ws = Workspace(robot)
    box, tilt = REACH * np.asarray(span.box_mm), np.deg2rad(REACH * span.tilt_deg)
    u = rng.choice([-1.0, 1.0], (n, 6))
    faces = np.arange(n) % 2 == 1
    free = rng.uniform(-1.0, 1.0, (n, 6))
    keep = np.eye(6, dtype=bool)[rng.integers(0, 6, n)]
    u[faces] = np.where(keep[faces], u[faces], free[faces])
    best = np.full(n, -1)
    poses = []
    for k, scale in enumerate(EDGE_SCALES):
        P = ws.home_position + scale * u[:, :3] * box
        R = Rotation.from_rotvec(scale * u[:, 3:] * tilt).as_matrix() @ ws.home_rotation
        ok = reachable(robot, P, R) & (best < 0)
        best[ok] = k
        poses.append((P, R))
    found = best >= 0
    P = np.stack([p for p, _ in poses])[best[found], np.where(found)[0]]
    R = np.stack([r for _, r in poses])[best[found], np.where(found)[0]]
    return P, R


def session_ranges(meas: Measurements, robot: Robot) -> PoseRanges:
    """The box (mm) and tilt (deg) about ``robot``'s home that the session's poses span."""
    ws = Workspace(robot)
    box = np.max(np.abs(meas.position - ws.home_position), axis=0)
    rel = meas.rotations * Rotation.from_matrix(ws.home_rotation).inv()
    tilt = float(np.max(np.abs(rel.as_rotvec(degrees=True))))
    return PoseRanges(box_mm=tuple(np.maximum(box, 1.0).tolist()), tilt_deg=max(tilt, 0.1))


def reachable(robot: Robot, P: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(K,) poses within the strokes (``leg_range_mm`` on readings), the joints' limits
    (``joint_limit_deg`` from each leg's direction at home, else 50° from the base's and
    platform's normals), and away from singularities (:data:`~hexcal.estimate.nbp.MAX_CONDITION`)."""
    limit = robot.joint_limit_deg
    ws = Workspace(robot, limits=Limits(limit or 50.0, limit or 50.0))
    ok = ws.feasible(P, R)
    if limit is not None:
        from hexcal.estimate.predict import Poses

        base, plat = LegModel(robot).joint_angles(Poses(P, R))
        ok &= np.maximum(base, plat).max(axis=1) <= limit
    return ok & (condition_number(robot.a, robot.b, P, Rotation.from_matrix(R)) <= MAX_CONDITION)


def _with_edges(problem: Problem, robot: Robot, pool, rng: np.random.Generator):
    """The planner's candidates: ``pool`` (uniform: the random poses a plan is compared with
    are drawn from it alone) and as many on the session's edge (:func:`_edge_candidates`),
    interleaved so that a schedule's first :data:`SCHEDULE_CANDIDATES` hold both."""
    edge = _edge_candidates(problem, robot, len(pool[0]), rng)
    k = min(len(pool[0]), len(edge[0]))
    P = np.concatenate([np.stack([pool[0][:k], edge[0][:k]], 1).reshape(-1, 3), pool[0][k:]])
    R = np.concatenate([np.stack([pool[1][:k], edge[1][:k]], 1).reshape(-1, 3, 3), pool[1][k:]])
    return P, R
