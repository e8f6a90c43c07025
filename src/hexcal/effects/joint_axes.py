"""A joint whose two rotation axes do not intersect: the length its offset adds to a leg.

A U-joint (or a cardan-built spherical joint) turns about a first axis ``u`` fixed in the body
it is mounted on, and a second axis on the cross-piece, perpendicular to ``u``, to which the leg
is fixed: the leg's line meets the second axis at right angles. In the ideal joint the two axes
meet at the joint's centre ``c`` (a base point ``a_k`` or a platform point ``b_k``). When they
miss each other by ``e`` along their common normal, the leg starts (or ends) on the second axis,
``e`` from the first.

**The exact length.** Let ``v`` be the vector from ``c`` to the leg's other joint (length ``L``
= the ideal model's ``|P + R b_k − a_k|``), ``X = v·u`` its component along the fixed axis and
``ρ = |v × u|`` its distance from it. The second axis is perpendicular to ``u`` and to the leg,
so the leg lies in the plane through ``c`` perpendicular to the second axis; that plane contains
``u`` and ``v``. In it, the second axis is the point ``e`` from ``c`` along the common normal,
which points across ``u`` away from the leg's other end (``e`` > 0) or towards it (``e`` < 0).
The joint-to-joint length the encoder serves is then

    L' = sqrt(X² + (ρ + e)²)   (mm),

and the model's contribution (what is added to ``reading + offset`` to give ``L``) is ``L − L'``.

**Linear in e.** ``L' = L + e·ρ/L + e²·X²/(2L³) + …`` and ``ρ/L = |u × n|`` = sin of the angle
between the leg's direction ``n`` and the fixed axis, so at a fixed axis direction the
contribution is, to first order,

    ΔL = −e · |u × n|   (mm),

linear in ``e`` as the effect contract asks. The second-order term is ``e²·cos²φ/(2L)``, small
because the leg stays nearly across its joint's fixed axis (``cos φ`` small): on a simulated Left
Hand session (legs 146–271 mm) at ``e`` = 1 mm it is at most 0.4 µm for a base joint and 0.8 µm
for a platform joint — under a tenth of the tracker's 10 µm. The simulator injects the exact
``L − L'`` (:meth:`~hexcal.effects.base.Effect.true_contribution`), so simulated sessions test
the linearisation.

**What the geometry absorbs.** Write ``s(n) = |u × n|`` around the leg's direction at home
``n₀``: its constant part ``e·s(n₀)`` is a change of ``offset_k``; its part linear in ``n``,
``−e·(u·n₀)/s(n₀)·(u·n)``, is what a shift of the joint centre along its fixed axis gives (``a_k``
for a base joint; for a platform joint, ``n`` taken in the platform frame, ``b_k``) — nothing
when the fixed axis is across the leg at home, the default, where ``s ≈ 1 − (u·n)²/2``. What
is left is that curvature, and of it the geometry takes whatever follows the legs' tilt over the
session's poses (mostly through ``a_k``'s or ``b_k``'s height). On a standard simulated Left
Hand session (184 poses) that leaves 0.3 % of the ``ujoint`` basis' size (principal angle to the
geometry's Jacobian 0.15–0.2°) and 1.3 % of ``balljoint``'s (0.7–1.1°). Without noise, a 1 mm
offset on every joint leaves Model 42 a residual of 3.5 µm RMS (up to 28 µm at the poses that
swing the legs most) at the base joints and 14 µm RMS (up to 90 µm) at the platform joints; with
the standard noise the session resolves the offsets to about ±0.1 mm and ±0.025 mm. The fit of
the linear model reads a 1 mm offset 0.5 % short (the second-order term), far inside that.
What separates the rest is each leg swung far towards and away from its joint's fixed axis, on
both sides: about the joint's second axis for a base joint; by tilting the platform, for a
platform joint.
"""

from __future__ import annotations

import numpy as np

from hexcal.effects.base import EffectData
from hexcal.model.robot import Robot

#: Below this norm of ``z × n`` a leg counts as vertical at home: the default axis is then the
#: tangent of its joint's circle about the z axis instead.
VERTICAL = 1e-6


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _across(direction: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """(6, 3) unit vectors perpendicular to z and to ``direction`` (6, 3); where ``direction`` is
    along z, perpendicular to z and to ``fallback`` (the joint's radius); failing that, x."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, direction)
    flat = np.linalg.norm(axis, axis=-1) < VERTICAL
    axis[flat] = np.cross(z, fallback[flat])
    flat = np.linalg.norm(axis, axis=-1) < VERTICAL
    axis[flat] = [1.0, 0.0, 0.0]
    return _unit(axis)


def home_legs(robot: Robot, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(leg directions (6, 3) at the home pose in the base frame, the home rotation (3, 3)) at
    the geometry ``a``, ``b`` (6, 3) mm."""
    from scipy.spatial.transform import Rotation

    q = robot.home.quaternion
    rot = Rotation.from_quat(q, scalar_first=True).as_matrix()
    legs = np.asarray(robot.home.position, float) + b @ rot.T - a
    return _unit(legs), rot


def base_axes(robot: Robot, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(6, 3) unit fixed axes of the base U-joints, base frame: robot.json's ``ujoint_axes``,
    else each horizontal (⊥ z) and perpendicular to its leg at home."""
    if robot.ujoint_axes is not None:
        return _unit(np.asarray(robot.ujoint_axes, float))
    n0, _ = home_legs(robot, a, b)
    return _across(n0, a)


def platform_axes(robot: Robot, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(6, 3) unit fixed axes of the platform joints, platform frame: robot.json's
    ``balljoint_axes``, else each perpendicular to the platform's z and to its leg at home."""
    if robot.balljoint_axes is not None:
        return _unit(np.asarray(robot.balljoint_axes, float))
    n0, rot = home_legs(robot, a, b)
    return _across(n0 @ rot, b)  # the home leg directions in the platform frame


def sines(data: EffectData, axes: np.ndarray) -> np.ndarray:
    """(M, 6) ``|u × n|`` for fixed axes ``axes`` (6, 3) or (M, 6, 3), measurement frame, and
    the legs' directions at the evaluation geometry."""
    n = _unit(data.leg_vectors)
    return np.linalg.norm(np.cross(np.broadcast_to(axes, n.shape), n), axis=-1)


def exact(data: EffectData, axes: np.ndarray, e: np.ndarray) -> np.ndarray:
    """(M, 6) mm ``L − sqrt(X² + (ρ + e)²)``: the exact contribution of axis offsets ``e`` (6,)
    mm with fixed axes ``axes`` (6, 3) or (M, 6, 3) in the measurement frame."""
    v = data.leg_vectors
    u = np.broadcast_to(axes, v.shape)
    x = np.einsum("mki,mki->mk", v, u)
    rho = np.linalg.norm(np.cross(u, v), axis=-1)
    return np.linalg.norm(v, axis=-1) - np.sqrt(x**2 + (rho + e) ** 2)
