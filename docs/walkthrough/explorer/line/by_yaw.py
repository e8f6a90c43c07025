"""by_yaw: the unexplained residual of measurements.csv (184 poses) follows the platform
yaw (from home). Written by hexcal diagnose: along it, a straight line on every leg
explains 98 % of the excess over the noise floor on held-out poses (held-out RMS 40.25 →
11.53 µm once added); the shape's constant is left to the leg offsets. Loaded as it is,
it is that shape; edit it to the physics you suspect (a formula in place of the shape,
fewer parameters, a plausible range), then pass the file back and add the effect:

    --effects FILE.py --add by_yaw
"""

from hexcal.effects import register
from hexcal.effects.explored import ExploredEffect, Shape

#: The lead's shape, as the explorer fitted it (a straight line); legs 1-6 in each row.
SHAPE = Shape.from_dict(
    {'centre': [0.20876956017685888, 0.20876956017685888, 0.20876956017685888,
                0.20876956017685888, 0.20876956017685888, 0.20876956017685888],
     'half': [15.219245269001249, 15.219245269001249, 15.219245269001249,
              15.219245269001249, 15.219245269001249, 15.219245269001249],
     'kind': 'line',
     'legs': [1, 2, 3, 4, 5, 6],
     'shared': False}
)


@register
class ByYaw(ExploredEffect):
    name = "by_yaw"
    #: The covariate (hexcal.effects.covariates): platform yaw (from home), deg.
    covariate = "yaw"
    shape = SHAPE
    physics = (
        "The leg length departs from the model along the platform yaw (from home): a "
        "straight line (written by hexcal diagnose; replace it with the physics you "
        "suspect: something that follows the platform's yaw (an encoder cable dragged"
        " as it turns, a joint that binds at an angle))."
    )
    separating_motion = (
        "poses that spread the platform yaw (from home) over its whole range"
    )

    # To put the physics you suspect in place of the shape, give the effect its own
    # parameters and basis (docs/effects.md), e.g. one parameter per leg:
    #
    #     def params(self, robot):
    #         return [ParamSpec(f"by_yaw.k{leg}", "µm", (-1000.0, 1000.0), 1e-3)
    #                 for leg in range(1, 7)]
    #
    #     def basis(self, data):  # (M, 6, 6) mm per µm
    #         u = covariate_values("yaw", data)  # (M, 6) platform yaw (from home)
    #         return diagonal(1e-3 * your_formula(u))
    #
    # (import ParamSpec and diagonal from hexcal.effects, covariate_values from
    # hexcal.effects.covariates).
