"""``thermal``: expansion of the legs with the structure temperature."""

from __future__ import annotations

import numpy as np

from hexcal.effects.base import Effect, EffectData, ParamSpec, register

#: Reference temperature of the design lengths, degC.
T_REF = 20.0


@register
class Thermal(Effect):
    name = "thermal"
    physics = (
        "The legs expand with the structure's temperature: length·(1 + α·(T − 20 °C)), "
        "α about 12 ppm/K for steel, 23 for aluminium."
    )
    needs = ("temperature column",)
    uses_geometry = True
    separating_motion = "poses recorded over a temperature change of a few kelvin, with long and short legs at each temperature"

    def params(self, robot) -> list[ParamSpec]:
        return [ParamSpec("thermal.alpha", "ppm/K", (-5.0, 40.0), 1e-6)]

    def basis(self, data: EffectData) -> np.ndarray:
        length = data.readings + data.robot.offsets
        return ((data.temperature - T_REF)[:, None] * length * 1e-6)[..., None]

    def missing(self, data: EffectData) -> str | None:
        if data.temperature is None:
            return "the measurements have no temperature column"
        if np.ptp(data.temperature) < 0.2:
            return f"the temperature hardly changed ({np.ptp(data.temperature):.2f} K)"
        return None

    def cannot_predict(self, data: EffectData) -> str | None:
        if data.temperature is None:
            return "give the structure temperature (degC) of every pose"
        return None
