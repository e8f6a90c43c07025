"""by_stroke: the unexplained residual of measurements.csv (184 poses) follows the position
along the stroke (the reading). Written by hexcal diagnose: along it, a periodic error
of period 7.3 mm on every leg explains 99 % of the excess over the noise floor on
held-out poses (held-out RMS 26.25 → 11.39 µm once added); the shape's constant is left
to the leg offsets. Loaded as it is, it is that shape; edit it to the physics you
suspect (a formula in place of the shape, fewer parameters, a plausible range), then
pass the file back and add the effect:

    --effects FILE.py --add by_stroke
"""

from hexcal.effects import register
from hexcal.effects.explored import ExploredEffect, Shape

#: The lead's shape, as the explorer fitted it (a periodic error of period 7.3 mm); legs 1-6 in each row.
SHAPE = Shape.from_dict(
    {'kind': 'periodic',
     'legs': [1, 2, 3, 4, 5, 6],
     'period': 7.300105744400398,
     'shared': False}
)


@register
class ByStroke(ExploredEffect):
    name = "by_stroke"
    #: The covariate (hexcal.effects.covariates): position along the stroke (the reading), mm.
    covariate = "stroke"
    shape = SHAPE
    physics = (
        "The leg length departs from the model along the position along the stroke "
        "(the reading): a periodic error of period 7.3 mm (written by hexcal "
        "diagnose; replace it with the physics you suspect: a cyclic error along the "
        "position along the stroke (the reading) (a scale, a screw, a gear))."
    )
    separating_motion = (
        "poses that spread the position along the stroke (the reading) over its whole"
        " range"
    )

    # To put the physics you suspect in place of the shape, give the effect its own
    # parameters and basis (docs/effects.md), e.g. one parameter per leg:
    #
    #     def params(self, robot):
    #         return [ParamSpec(f"by_stroke.k{leg}", "µm", (-1000.0, 1000.0), 1e-3)
    #                 for leg in range(1, 7)]
    #
    #     def basis(self, data):  # (M, 6, 6) mm per µm
    #         u = covariate_values("stroke", data)  # (M, 6) position along the stroke (the reading)
    #         return diagonal(1e-3 * your_formula(u))
    #
    # (import ParamSpec and diagonal from hexcal.effects, covariate_values from
    # hexcal.effects.covariates).
