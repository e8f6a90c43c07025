"""``offset``: a constant error in each leg's length offset (Model 36 → Model 42)."""

from __future__ import annotations

import numpy as np

from hexcal.effects.base import Effect, EffectData, ParamSpec, diagonal, register


@register
class Offset(Effect):
    name = "offset"
    physics = "Each encoder's zero is a constant length away from the design value: length = reading + offset_k."
    separating_motion = "poses that change each leg's direction (Type III swings, free poses spread over the workspace)"

    def params(self, robot) -> list[ParamSpec]:
        # Named as the refinement names the Model 42 offsets, so both read the same.
        return [ParamSpec(f"offset{k}", "mm", (-2.0, 2.0)) for k in range(1, 7)]

    def basis(self, data: EffectData) -> np.ndarray:
        return diagonal(np.ones_like(data.readings))
