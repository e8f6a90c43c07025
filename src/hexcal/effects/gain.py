"""``gain``: an encoder scale error per leg."""

from __future__ import annotations

import numpy as np

from hexcal.effects.base import Effect, EffectData, ParamSpec, diagonal, per_leg, register


@register
class Gain(Effect):
    name = "gain"
    physics = "An encoder whose counts-per-mm is slightly off reads lengths scaled by (1 + g_k): length = offset + (1 + g_k)·reading."
    separating_motion = (
        "each leg driven over its whole stroke (Type I poses with long and short legs)"
    )

    def params(self, robot) -> list[ParamSpec]:
        return per_leg("gain", "g", "ppm", (-5000.0, 5000.0), 1e-6)

    def basis(self, data: EffectData) -> np.ndarray:
        return diagonal(data.readings * 1e-6)
