"""``leadscrew``: periodic lead-screw error per leg."""

from __future__ import annotations

import numpy as np

from hexcal.effects.base import Effect, EffectData, ParamSpec, leg_of, register, with_priors

#: Plausible amplitude of each of the sine and cosine terms, mm: ± 0.1. A rolled trapezoidal
#: screw wobbles by tens of µm per turn; a ground ball screw by a few µm.
PLAUSIBLE_MM = (-0.1, 0.1)
#: Identifiability: each term must be resolved to 5 µm.
RESOLUTION_MM = 0.005


@register
class Leadscrew(Effect):
    name = "leadscrew"
    physics = (
        "A lead screw's thread is not perfectly uniform: the length error repeats once per turn, "
        "s_k·sin(2π·reading/pitch) + c_k·cos(…)."
    )
    needs = ("leadscrew_pitch_mm in robot.json",)
    separating_motion = (
        "readings spread over several screw pitches with steps finer than half a pitch"
    )

    def params(self, robot) -> list[ParamSpec]:
        specs = []
        for k in range(1, 7):
            for term in ("s", "c"):
                specs.append(
                    ParamSpec(f"leadscrew.{term}{k}", "mm", PLAUSIBLE_MM, 1.0, RESOLUTION_MM)
                )
        return with_priors(self.name, specs, robot)

    def basis(self, data: EffectData) -> np.ndarray:
        pitch = data.robot.leadscrew_pitch_mm
        if not pitch:
            raise ValueError("leadscrew: robot.json has no leadscrew_pitch_mm")
        phase = 2 * np.pi * data.readings / float(pitch)
        out = np.zeros((*data.readings.shape, 12))
        k = np.arange(6)
        out[:, k, 2 * k] = np.sin(phase)
        out[:, k, 2 * k + 1] = np.cos(phase)
        return out

    def missing(self, data: EffectData) -> str | None:
        if not data.robot.leadscrew_pitch_mm:
            return "robot.json has no leadscrew_pitch_mm"
        return None

    def cannot_predict(self, data: EffectData) -> str | None:
        return self.missing(data)

    def meaning(self, name: str, value: float, robot) -> str:
        return (
            f"a periodic error of {1000 * abs(value):.3g} µm per screw turn in leg {leg_of(name)} "
            "— check leadscrew_pitch_mm"
        )
