"""``compliance``: axial deflection of the legs under the platform's weight."""

from __future__ import annotations

import numpy as np

from hexcal.effects.base import Effect, EffectData, ParamSpec, register

G = 9.80665  # m/s²


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


@register
class Compliance(Effect):
    name = "compliance"
    physics = "Each leg shortens under its axial load like a spring: ΔL = −c·f, the forces from the platform's weight by statics."
    needs = ("platform mass (robot.json platform_mass_kg)",)
    uses_geometry = True
    separating_motion = (
        "poses that shift the load between legs: the platform far off-centre and tilted"
    )

    def params(self, robot) -> list[ParamSpec]:
        return [ParamSpec("compliance.c", "µm/N", (0.0, 5.0), 1e-3)]

    def basis(self, data: EffectData) -> np.ndarray:
        mass = data.robot.platform_mass_kg
        com = getattr(data.robot, "platform_com_mm", None)
        f = leg_forces(data, mass, None if com is None else np.asarray(com, float))
        return (-f * 1e-3)[..., None]

    def missing(self, data: EffectData) -> str | None:
        if not data.robot.platform_mass_kg:
            return "robot.json has no platform_mass_kg, so the leg forces are unknown"
        return None

    def cannot_predict(self, data: EffectData) -> str | None:
        return self.missing(data)
