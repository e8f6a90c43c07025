"""Inverse and forward kinematics and the platform Jacobian of a Gough platform.

Conventions: a pose is (P, R): a point x in platform coordinates sits at ``P + R x`` in the
measurement frame. ``a`` (6, 3) mm base points, ``b`` (6, 3) mm platform points.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from hexcal.errors import RefusedError


def rotation_matrices(rotations: Rotation) -> np.ndarray:
    """(N, 3, 3) matrices of a Rotation (a single rotation gives (1, 3, 3))."""
    m = rotations.as_matrix()
    return m[None] if m.ndim == 2 else m


def leg_vectors(
    a: np.ndarray, b: np.ndarray, position: np.ndarray, rotations: Rotation
) -> np.ndarray:
    """Vectors from base to platform attachment, ``P + R b_k - a_k``: (N, K, 3) mm.

    a, b: (K, 3) mm; position: (N, 3) mm; rotations: N rotations.
    """
    r = rotation_matrices(rotations)
    p = np.atleast_2d(position)
    return p[:, None, :] + np.einsum("nij,kj->nki", r, np.atleast_2d(b)) - np.atleast_2d(a)[None]


def inverse_kinematics(
    a: np.ndarray, b: np.ndarray, position: np.ndarray, rotations: Rotation
) -> np.ndarray:
    """Geometric leg lengths ``|P + R b_k - a_k|``: (N, K) mm for N poses."""
    return np.linalg.norm(leg_vectors(a, b, position, rotations), axis=-1)


def platform_jacobian(
    a: np.ndarray, b: np.ndarray, position: np.ndarray, rotations: Rotation
) -> np.ndarray:
    """Leg-rate Jacobian, (N, 6, 6): ``dL = J @ [dP; dtheta]``.

    dP (3,) mm is a translation and dtheta (3,) rad a small rotation, both in the measurement
    frame (``R -> exp([dtheta]x) R``). Row k is ``[n_k, (R b_k) x n_k]`` with n_k the unit leg
    vector. Its transpose maps leg forces to the wrench on the platform: ``w = J.T @ f``.
    """
    v = leg_vectors(a, b, position, rotations)
    n = v / np.linalg.norm(v, axis=-1, keepdims=True)
    rb = np.einsum("nij,kj->nki", rotation_matrices(rotations), np.atleast_2d(b))
    return np.concatenate([n, np.cross(rb, n)], axis=-1)


def condition_number(
    a: np.ndarray, b: np.ndarray, position: np.ndarray, rotations: Rotation
) -> np.ndarray:
    """Condition number (N,) of the leg-rate Jacobian made dimensionless (its moment columns
    divided by the mean platform radius, mm): about 5 near home for a typical Gough platform,
    infinite at a singularity, where the legs no longer hold the platform in every direction."""
    jac = platform_jacobian(a, b, position, rotations)
    radius = float(np.linalg.norm(np.atleast_2d(b), axis=-1).mean())
    jac[..., 3:] /= radius
    return np.linalg.cond(jac)


class ForwardKinematicsError(RefusedError, RuntimeError):
    """No pose reproduces the given leg lengths within tolerance."""


#: Evaluations one start of :func:`forward_kinematics` may take.
MAX_NFEV = 100


def forward_kinematics(
    a: np.ndarray,
    b: np.ndarray,
    lengths: np.ndarray,
    guess_position: np.ndarray | None = None,
    guess_rotation: Rotation | None = None,
    tol_mm: float = 1e-6,
) -> tuple[np.ndarray, Rotation]:
    """The pose (P (3,) mm, R) whose legs have ``lengths`` (6,) mm.

    Gough platforms have up to 40 assembly modes, so the solution returned is the one reached
    from the guess (default: above the base centroid at the mean leg length, level). If the
    solve does not close the legs to ``tol_mm``, restarts from a few perturbed guesses are tried
    before giving up, so a poor guess does not end in a local minimum.
    """
    lengths = np.asarray(lengths, float)
    if guess_position is None:
        guess_position = np.asarray(a, float).mean(axis=0) + np.array(
            [0.0, 0.0, float(np.mean(lengths))]
        )
    if guess_rotation is None:
        guess_rotation = Rotation.identity()

    def residual(x: np.ndarray) -> np.ndarray:
        rot = Rotation.from_rotvec(x[3:]) * guess_rotation
        return inverse_kinematics(a, b, x[None, :3], rot)[0] - lengths

    def jac(x: np.ndarray) -> np.ndarray:
        rot = Rotation.from_rotvec(x[3:]) * guess_rotation
        # Small-angle Jacobian; exact at x[3:] = 0 and good enough for Gauss-Newton elsewhere.
        return platform_jacobian(a, b, x[None, :3], rot)[0]

    rng = np.random.default_rng(0)
    best = None
    for attempt in range(8):
        x0 = np.concatenate([guess_position, np.zeros(3)])
        if attempt:
            x0 = x0 + rng.normal(0, [5, 5, 5, 0.1, 0.1, 0.1])
        # A solve that converges takes a few tens of evaluations; lengths no pose closes would
        # otherwise run MINPACK's default 600 per start (eight starts, for every such row).
        sol = least_squares(
            residual, x0, jac=jac, method="lm", xtol=1e-15, ftol=1e-15, max_nfev=MAX_NFEV
        )
        if best is None or sol.cost < best.cost:
            best = sol
        if np.max(np.abs(sol.fun)) < tol_mm:
            break
    assert best is not None
    if np.max(np.abs(best.fun)) >= tol_mm:
        raise ForwardKinematicsError(
            f"forward kinematics did not close the legs: worst leg error "
            f"{np.max(np.abs(best.fun)):.3g} mm; the lengths may be out of the workspace"
        )
    return best.x[:3], Rotation.from_rotvec(best.x[3:]) * guess_rotation
