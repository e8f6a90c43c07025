"""by_stroke: the unexplained residual of measurements.csv (184 poses) follows the position
along the stroke (the reading). Written by hexcal diagnose: along it, a step (a change
point) on legs 1, 3, 4 explains 97 % of the excess over the noise floor on held-out
poses (held-out RMS 25.87 → 11.89 µm once added); the shape's constant is left to the
leg offsets. Loaded as it is, it is that shape; edit it to the physics you suspect (a
formula in place of the shape, fewer parameters, a plausible range), then pass the file
back and add the effect:

    --effects FILE.py --add by_stroke
"""

from hexcal.effects import register
from hexcal.effects.explored import ExploredEffect, Shape

#: The lead's shape, as the explorer fitted it (a step (a change point)); legs 1-6 in each row.
SHAPE = Shape.from_dict(
    {'kind': 'step',
     'legs': [1, 3, 4],
     'shared': False,
     'split': [64.8724, 59.3754, 68.29814999999999, 62.4301, 42.8707,
               96.46385000000001]}
)


@register
class ByStroke(ExploredEffect):
    name = "by_stroke"
    #: The covariate (hexcal.effects.covariates): position along the stroke (the reading), mm.
    covariate = "stroke"
    shape = SHAPE
    physics = (
        "The leg length departs from the model along the position along the stroke "
        "(the reading): a step (a change point) (written by hexcal diagnose; replace "
        "it with the physics you suspect: an encoder scale that bends or repeats "
        "along the stroke, a dent or a worn stretch of a screw or a rail)."
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
