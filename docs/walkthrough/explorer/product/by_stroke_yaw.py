"""by_stroke_yaw: the unexplained residual of measurements.csv (184 poses) follows the
position along the stroke (the reading) × platform yaw (from home). Written by hexcal
diagnose: along it, a bilinear surface (the product and its two lines) on every leg
explains 100 % of the excess over the noise floor on held-out poses (held-out RMS 54.71
→ 11.58 µm once added); the shape's constant is left to the leg offsets. Loaded as it
is, it is that shape; edit it to the physics you suspect (a formula in place of the
shape, fewer parameters, a plausible range), then pass the file back and add the effect:

    --effects FILE.py --add by_stroke_yaw
"""

from hexcal.effects import register
from hexcal.effects.explored import ExploredEffect, Shape

#: The lead's shape, as the explorer fitted it (a bilinear surface (the product and its two lines)); legs 1-6 in each row.
SHAPE = Shape.from_dict(
    {'centre': [53.72585, 56.7665, 61.589749999999995, 58.83585, 55.386399999999995,
                58.70345],
     'centre2': [0.20876956017685888, 0.20876956017685888, 0.20876956017685888,
                 0.20876956017685888, 0.20876956017685888, 0.20876956017685888],
     'half': [56.408350000000006, 53.0713, 45.77605, 52.67825, 56.3416, 48.50745],
     'half2': [15.219245269001249, 15.219245269001249, 15.219245269001249,
               15.219245269001249, 15.219245269001249, 15.219245269001249],
     'kind': 'product',
     'legs': [1, 2, 3, 4, 5, 6],
     'shared': False}
)


@register
class ByStrokeYaw(ExploredEffect):
    name = "by_stroke_yaw"
    #: The covariate (hexcal.effects.covariates): position along the stroke (the reading) × platform yaw (from home), mm·deg.
    covariate = "stroke*yaw"
    shape = SHAPE
    physics = (
        "The leg length departs from the model along the position along the stroke "
        "(the reading) × platform yaw (from home): a bilinear surface (the product "
        "and its two lines) (written by hexcal diagnose; replace it with the physics "
        "you suspect: an error along the position along the stroke (the reading) "
        "whose size changes with the platform yaw (from home) (or the other way "
        "round): an encoder scale that bends or repeats along the stroke, a dent or a"
        " worn stretch of a screw or a rail, acting with something that follows the "
        "platform's yaw (an encoder cable dragged as it turns, a joint that binds at "
        "an angle))."
    )
    separating_motion = (
        "poses that spread the position along the stroke (the reading) × platform yaw"
        " (from home) over its whole range"
    )

    # To put the physics you suspect in place of the shape, give the effect its own
    # parameters and basis (docs/effects.md), e.g. one parameter per leg:
    #
    #     def params(self, robot):
    #         return [ParamSpec(f"by_stroke_yaw.k{leg}", "µm", (-1000.0, 1000.0), 1e-3)
    #                 for leg in range(1, 7)]
    #
    #     def basis(self, data):  # (M, 6, 6) mm per µm
    #         u = covariate_values("stroke*yaw", data)  # (M, 6) position along the stroke (the reading) × platform yaw (from home)
    #         return diagonal(1e-3 * your_formula(u))
    #
    # (import ParamSpec and diagonal from hexcal.effects, covariate_values from
    # hexcal.effects.covariates).
