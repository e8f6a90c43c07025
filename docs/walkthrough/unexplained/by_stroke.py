"""by_stroke: the unexplained residual of docs/walkthrough/unexplained/measurements.csv
(184 poses) follows the position along the stroke (the reading). Written by hexcal
diagnose: along it, a parabola on legs 1, 2, 4, 5, 6 explains 98 % of the excess over
the noise floor; the shape's constant is left to the leg offsets. Edit it to the physics
you suspect (a formula in place of the shape, fewer parameters, a plausible range), then
pass the file back and add the effect:

    --effects FILE.py --add by_stroke
"""

import numpy as np

from hexcal.effects import Effect, EffectData, ParamSpec, register

#: The legs (1-6) that carry the shape, and its parameters per leg.
LEGS = (1, 2, 4, 5, 6)
PER_LEG = 2
#: Each leg's shape is a polynomial of this degree in its position along the stroke (the
#: reading), mm about CENTRE, over HALF (the session's own range of each leg; legs 1-6).
DEGREE = 2
CENTRE = np.array([72.77275, 54.44235, 61.9459, 60.7431, 58.04305, 64.5401])
HALF = np.array([51.77665, 48.84575, 51.0019, 47.322, 53.16975, 56.7908])


def covariate(data: EffectData) -> np.ndarray:
    """(M, 6) each leg's position along the stroke (the reading), mm."""
    return np.asarray(data.readings, float)


def shape(u: np.ndarray, k: int) -> np.ndarray:
    """(M, DEGREE) leg k's (0-based) shape columns: powers 1 .. DEGREE of its covariate about
    the middle of its range, over half the range (the constant is the leg's offset)."""
    x = (u - CENTRE[k]) / HALF[k]
    return np.column_stack([x**j for j in range(1, DEGREE + 1)])


@register
class ByStroke(Effect):
    name = "by_stroke"
    physics = (
        "The leg length departs from the model along the position along the stroke "
        "(the reading): a parabola per leg (written by hexcal diagnose; replace it "
        "with the physics you suspect: an encoder scale that bends along the stroke, "
        "a dent or a worn stretch of a screw or a rail)."
    )
    separating_motion = (
        "poses that spread each leg's position along the stroke (the reading) over "
        "its whole range"
    )
    uses_geometry = False

    def params(self, robot) -> list[ParamSpec]:
        return [
            ParamSpec(f"by_stroke.c{j}_leg{leg}", "µm", (-1000.0, 1000.0), 1e-3, 20.0)
            for leg in LEGS
            for j in range(1, PER_LEG + 1)
        ]

    def basis(self, data: EffectData) -> np.ndarray:
        """(M, 6, len(LEGS) * PER_LEG) mm per µm: each leg's shape in its own columns."""
        u = covariate(data)
        out = np.zeros((len(u), 6, len(LEGS) * PER_LEG))
        for i, leg in enumerate(LEGS):
            cols = slice(i * PER_LEG, (i + 1) * PER_LEG)
            out[:, leg - 1, cols] = 1e-3 * shape(u[:, leg - 1], leg - 1)
        return out
