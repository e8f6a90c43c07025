"""``thermal``: expansion of the legs with the structure temperature."""

from __future__ import annotations

import numpy as np

from hexcal.effects.base import Effect, EffectData, ParamSpec, register, with_priors

#: Reference temperature of the design lengths, degC.
T_REF = 20.0
#: Plausible expansion coefficient, ppm/K: −5 … 40, metal legs (steel 12, aluminium 23, brass
#: 19; Invar and carbon fibre near 0). Printed or plastic legs expand up to ~100 ppm/K: set
#: ``"plausible": {"thermal": [-5, 120]}`` for them.
PLAUSIBLE_PPM_K = (-5.0, 40.0)
#: Identifiability: α must be resolved to 2.25 ppm/K.
RESOLUTION_PPM_K = 2.25


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
        spec = ParamSpec("thermal.alpha", "ppm/K", PLAUSIBLE_PPM_K, 1e-6, RESOLUTION_PPM_K)
        return with_priors(self.name, [spec], robot)

    def basis(self, data: EffectData) -> np.ndarray:
        if data.temperature is None:
            raise ValueError("thermal: the measurements have no temperature column")
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

    def meaning(self, name: str, value: float, robot) -> str:
        return (
            f"an expansion of {value:.3g} ppm/K (steel 12, aluminium 23) — check the temperature "
            "sensor and what it measures"
        )
