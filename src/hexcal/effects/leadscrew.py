"""``leadscrew``: periodic lead-screw error per leg."""

from __future__ import annotations

import numpy as np

from hexcal.effects.base import Effect, EffectData, ParamSpec, register


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
            specs.append(ParamSpec(f"leadscrew.s{k}", "mm", (-0.05, 0.05)))
            specs.append(ParamSpec(f"leadscrew.c{k}", "mm", (-0.05, 0.05)))
        return specs

    def basis(self, data: EffectData) -> np.ndarray:
        phase = 2 * np.pi * data.readings / float(data.robot.leadscrew_pitch_mm)
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
