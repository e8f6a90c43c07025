"""``offset``: a constant error in each leg's length offset (Model 36 → Model 42)."""

from __future__ import annotations

import numpy as np

from hexcal.effects.base import Effect, EffectData, ParamSpec, diagonal, register, with_priors

#: Plausible departure of an offset from its design value, mm: ± 10. Legs whose length at zero
#: reading was measured by hand (a tape, a calliper across the joints) are off by a few mm; a
#: machined hexapod's drawing is good to a few tenths (set ``"plausible": {"offset": [-1, 1]}``).
PLAUSIBLE_MM = (-10.0, 10.0)
#: Identifiability: an offset must be resolved to 0.2 mm.
RESOLUTION_MM = 0.2


@register
class Offset(Effect):
    name = "offset"
    physics = "Each encoder's zero is a constant length away from the design value: length = reading + offset_k."
    separating_motion = "poses that change each leg's direction (Type III swings, free poses spread over the workspace)"

    def params(self, robot) -> list[ParamSpec]:
        # Named as the refinement names the Model 42 offsets, so both read the same. The range
        # is the departure from the design's offset (the fit's flags add the design value).
        specs = [
            ParamSpec(f"offset{k}", "mm", PLAUSIBLE_MM, 1.0, RESOLUTION_MM) for k in range(1, 7)
        ]
        return with_priors(self.name, specs, robot)

    def basis(self, data: EffectData) -> np.ndarray:
        return diagonal(np.ones_like(data.readings))

    def meaning(self, name: str, value: float, robot) -> str:
        k = int(name[6:])
        d = value - float(robot.offsets[k - 1])
        side = "longer" if d > 0 else "shorter"
        return (
            f"leg {k} is {abs(d):.3g} mm {side} at zero reading than the design says — check "
            "its measured length at zero (leg_offsets in robot.json)"
        )
