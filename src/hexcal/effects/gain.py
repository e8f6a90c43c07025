"""``gain``: an encoder scale error per leg."""

from __future__ import annotations

import numpy as np

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

#: Plausible scale error, ppm: ± 10 %. Belt-, string- and screw-driven legs whose mm per count
#: (or per revolution) was measured by hand are off by several per cent (the first real robot
#: hexcal met: 5.5 %; its builders allowed ± 10 %); a factory-calibrated linear encoder is
#: within ± 5000 ppm (set ``"plausible": {"gain": [-5000, 5000]}`` for one).
PLAUSIBLE_PPM = (-100_000.0, 100_000.0)
#: Identifiability: the scale error must be resolved to 500 ppm (0.05 %).
RESOLUTION_PPM = 500.0


@register
class Gain(Effect):
    name = "gain"
    physics = "An encoder whose counts-per-mm is slightly off reads lengths scaled by (1 + g_k): length = offset + (1 + g_k)·reading."
    separating_motion = (
        "each leg driven over its whole stroke (Type I poses with long and short legs)"
    )

    def params(self, robot) -> list[ParamSpec]:
        specs = per_leg("gain", "g", "ppm", PLAUSIBLE_PPM, 1e-6, RESOLUTION_PPM)
        return with_priors(self.name, specs, robot)

    def basis(self, data: EffectData) -> np.ndarray:
        return diagonal(data.readings * 1e-6)

    def look_alike(self, values: np.ndarray, robot) -> str:
        # A tracker reading positions (1 + s) times too far from its origin sees every leg
        # (1 + s) times too long: |(1+s)(P + R b − a)| = (1+s)(ρ + offset), i.e. a gain s on every
        # leg with a, b and the offsets scaled by (1 + s) — the same residual, exactly.
        common = float(np.mean(values))
        spread = float(np.max(np.abs(np.asarray(values) - common)))
        return (
            f"gain looks exactly like a tracker scale error: a tracker whose positions read "
            f"{common:+.0f} ppm long gives every leg the same {common:+.0f} ppm gain, with the "
            "geometry scaled alike (an optical tracker's or a motion-capture system's scale is "
            "often a few hundred ppm off). Only the legs' "
            f"differences (up to ±{spread:.0f} ppm about that mean) are surely the encoders'; to "
            "tell the common part apart, measure a length standard (a calibrated bar, or an "
            "interferometer along a line) in the tracker's volume"
        )

    def meaning(self, name: str, value: float, robot) -> str:
        return (
            f"a {abs(value) / 1e4:.2g} % scale error of leg {leg_of(name)} — check the leg's "
            "mm-per-count"
        )
