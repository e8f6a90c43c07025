"""``compliance``: axial deflection of the legs under the platform's weight.

With ``platform_mass_kg`` in robot.json the parameter is the legs' compliance ``c`` (µm/N).
Without it the data still tell the product ``c·m``: the leg forces' pattern over the poses is set
by the geometry and the mass only scales it, so the basis is the leg forces of a 1 kg platform
(N/kg) and the parameter ``compliance.cm`` is in µm·kg/N (the legs' shortening, µm, per N/kg of
leg force per kg of platform). Divide it by the mass, once known, for ``c``.
"""

from __future__ import annotations

import numpy as np

from hexcal.effects.base import Effect, EffectData, ParamSpec, register, with_priors

G = 9.80665  # m/s²

#: Plausible compliance, µm/N: 0 … 20, legs no softer than 50 N/mm. A ball-screw leg is about
#: 1 µm/N (1000 N/mm); belt- and string-driven legs and printed joints are softer.
PLAUSIBLE_C = (0.0, 20.0)
#: Identifiability: c must be resolved to 0.25 µm/N.
RESOLUTION_C = 0.25
#: Plausible c·m, µm·kg/N: 0 … 400, the legs sagging at most about 0.65 mm under the platform's
#: own weight (c·m·g/6 per leg at home): 20 µm/N with a 20 kg platform, 4 µm/N with 100 kg.
PLAUSIBLE_CM = (0.0, 400.0)
#: Identifiability: c·m must be resolved to 5 µm·kg/N (0.25 µm/N on a 20 kg platform).
RESOLUTION_CM = 5.0


def leg_forces(data: EffectData, mass_kg: float, com: np.ndarray | None = None) -> np.ndarray:
    """(M, 6) N axial leg forces, compression positive, holding the platform's weight.

    Gravity is taken along −z of the measurement frame (a tracker registered to the base with
    z up). The weight acts at the platform origin, or at ``com`` (3,) mm in platform
    coordinates. Statics: ``Jᵀ f = −w`` with J rows ``[n_k, (R b_k) × n_k]``.
    """
    v = data.leg_vectors
    n = v / np.linalg.norm(v, axis=-1, keepdims=True)
    rb = np.einsum("mij,kj->mki", data.rotation, data.b)
    jt = np.concatenate([n, np.cross(rb, n)], axis=-1).transpose(0, 2, 1)  # (M, 6, 6) = Jᵀ
    # J's moment rows are about the platform origin, so the weight's moment is too (N·mm).
    lever = np.zeros_like(data.position) if com is None else data.rotation @ com
    force = np.broadcast_to([0.0, 0.0, -mass_kg * G], lever.shape)
    w = np.concatenate([force, np.cross(lever, force)], axis=-1)
    return np.linalg.solve(jt, -w[..., None])[..., 0]


def with_mass(robot) -> bool:
    """Whether the robot states its platform mass (then the parameter is ``c``, else ``c·m``)."""
    return bool(getattr(robot, "platform_mass_kg", None))


@register
class Compliance(Effect):
    name = "compliance"
    physics = "Each leg shortens under its axial load like a spring: ΔL = −c·f, the forces from the platform's weight by statics."
    needs = ("platform_mass_kg in robot.json for c itself (without it, c·m is fitted)",)
    uses_geometry = True
    separating_motion = (
        "poses that shift the load between legs: the platform far off-centre and tilted"
    )

    def params(self, robot) -> list[ParamSpec]:
        if with_mass(robot):
            spec = ParamSpec("compliance.c", "µm/N", PLAUSIBLE_C, 1e-3, RESOLUTION_C)
        else:
            spec = ParamSpec("compliance.cm", "µm·kg/N", PLAUSIBLE_CM, 1e-3, RESOLUTION_CM)
        return with_priors(self.name, [spec], robot)

    def basis(self, data: EffectData) -> np.ndarray:
        # Without the mass, the forces of a 1 kg platform: the parameter is then c·m.
        mass = data.robot.platform_mass_kg or 1.0  # what with_mass tests
        com = getattr(data.robot, "platform_com_mm", None)
        f = leg_forces(data, mass, None if com is None else np.asarray(com, float))
        return (-f * 1e-3)[..., None]

    def meaning(self, name: str, value: float, robot) -> str:
        if value < 0:
            return (
                "legs that lengthen under load are not physical — check that the tracker's z "
                "axis points up (gravity along −z) and platform_com_mm"
            )
        if value == 0:
            return "no compliance at all — check the range set in robot.json"
        if name == "compliance.c":
            return (
                f"legs of {1000 / value:.3g} N/mm — check the joints and mounts, and "
                "platform_mass_kg"
            )
        sag = value * G / 6  # µm per leg at home, the weight shared evenly
        size = f"{sag:.3g} µm" if sag < 1000 else f"{sag / 1000:.3g} mm"
        return (
            f"legs sagging about {size} under the platform's weight at home — check the joints "
            "and mounts, and that the tracker's z axis points up"
        )
