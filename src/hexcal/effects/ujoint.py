"""``ujoint``: the two axes of each base U-joint do not intersect (:mod:`.joint_axes`)."""

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

#: Plausible axis offset, mm: ± 2. A machined cardan joint's axes meet within a few hundredths
#: of a millimetre; a joint built from two bearings on a printed or welded cross, or a hobby
#: universal joint, misses by up to a millimetre or two.
PLAUSIBLE_MM = (-2.0, 2.0)
#: Identifiability: an offset must be resolved to 0.25 mm, a quarter of the 1 mm a loose joint
#: shows. Most of the effect is a change of the geometry (:mod:`.joint_axes`), so a standard
#: session resolves it only to about 0.1 mm: a finer resolution would refuse it there.
RESOLUTION_MM = 0.25


@register
class UJoint(Effect):
    name = "ujoint"
    physics = (
        "The two axes of each base U-joint miss each other by e_k along their common normal, so "
        "the leg starts e_k off its joint's centre: ΔL = −e_k·|u_k × n_k|, u_k the joint's fixed "
        "axis and n_k the leg's direction."
    )
    needs = (
        "ujoint_axes in robot.json, unless each fixed axis is horizontal and across its leg at home",
    )
    uses_geometry = True
    separating_motion = (
        "each leg swung far towards and away from its base joint's fixed axis, on both sides "
        "(free poses tilting the platform towards every leg)"
    )

    def params(self, robot) -> list[ParamSpec]:
        specs = per_leg("ujoint", "e", "mm", PLAUSIBLE_MM, 1.0, RESOLUTION_MM)
        return with_priors(self.name, specs, robot)

    def basis(self, data: EffectData) -> np.ndarray:
        axes = joint_axes.base_axes(data.robot, data.a, data.b)
        return diagonal(-joint_axes.sines(data, axes))

    def true_contribution(self, data: EffectData, values: np.ndarray) -> np.ndarray:
        axes = joint_axes.base_axes(data.robot, data.a, data.b)
        return joint_axes.exact(data, axes, np.asarray(values, float))

    def meaning(self, name: str, value: float, robot) -> str:
        return (
            f"leg {leg_of(name)}'s base joint axes {abs(value):.3g} mm apart — check the joint, "
            "and ujoint_axes in robot.json (the fixed axis' direction shapes the effect)"
        )
