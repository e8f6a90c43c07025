"""``balljoint``: the platform joints' counterpart of ``ujoint`` (:mod:`.joint_axes`).

The leg's axis misses the platform joint's centre. Two builds do that, and only one of them is an
effect the leg lengths can show:

- **A platform U-joint (or a cardan-built "ball") whose two axes do not intersect**: the first
  axis is fixed in the platform and turns with it. The derivation of :mod:`.joint_axes` holds
  with that axis taken at the pose, ``u_m = R_m u``: ``ΔL = −e_k·|R_m u_k × n_k|``. This is the
  effect. Its curvature follows the leg's direction *in the platform frame*, so it changes when
  the platform tilts, not only when it moves.
- **A leg end off the ball's centre** (a ball stud screwed in off the rod's axis, a socket
  bored off-centre): along the leg, the eccentricity is a constant length, ``offset_k``; across
  the leg, by ``d``, the joint-to-joint distance is ``sqrt(L'² + d²)`` (the leg's roll is held by
  its base U-joint, so ``d`` keeps its place on the leg), which adds ``d²/(2L)``: second order
  in ``d``, 3.4 µm for ``d`` = 1 mm on a 146 mm leg and 1.8 µm on a 271 mm one. The offsets take
  its mean and what is left is about 1.2 µm peak to peak over the Left Hand's whole stroke; on a
  standard simulated session it would raise χ² by 0.13 (it needs 52 to be named), and ``d``
  would have to reach about 6 mm to show. The lengths cannot show it, so it is no effect here. A
  plain shift of the ball's centre is a different ``b_k``.
"""

from __future__ import annotations

import numpy as np

from hexcal.effects import joint_axes
from hexcal.effects.base import (
    Effect,
    EffectData,
    ParamSpec,
    diagonal,
    leg_of,
    per_leg,
    register,
    with_priors,
)
from hexcal.effects.ujoint import PLAUSIBLE_MM, RESOLUTION_MM


def _axes_at_poses(data: EffectData) -> np.ndarray:
    """(M, 6, 3) the platform joints' fixed axes in the measurement frame at each pose."""
    axes = joint_axes.platform_axes(data.robot, data.a, data.b)
    return np.einsum("mij,kj->mki", data.rotation, axes)


@register
class BallJoint(Effect):
    name = "balljoint"
    physics = (
        "The two axes of each platform joint miss each other by e_k along their common normal, "
        "so the leg ends e_k off its joint's centre: ΔL = −e_k·|R·u_k × n_k|, u_k the joint's "
        "axis fixed in the platform."
    )
    needs = (
        "balljoint_axes in robot.json, unless each fixed axis is horizontal in the platform and "
        "across its leg at home",
    )
    uses_geometry = True
    separating_motion = (
        "the platform tilted so that each leg swings far towards and away from its platform "
        "joint's fixed axis, on both sides (tilts about both horizontal axes)"
    )

    def params(self, robot) -> list[ParamSpec]:
        specs = per_leg("balljoint", "e", "mm", PLAUSIBLE_MM, 1.0, RESOLUTION_MM)
        return with_priors(self.name, specs, robot)

    def basis(self, data: EffectData) -> np.ndarray:
        return diagonal(-joint_axes.sines(data, _axes_at_poses(data)))

    def true_contribution(self, data: EffectData, values: np.ndarray) -> np.ndarray:
        return joint_axes.exact(data, _axes_at_poses(data), np.asarray(values, float))

    def meaning(self, name: str, value: float, robot) -> str:
        return (
            f"leg {leg_of(name)}'s platform joint axes {abs(value):.3g} mm apart — check the "
            "joint, and balljoint_axes in robot.json (the fixed axis' direction shapes the effect)"
        )
