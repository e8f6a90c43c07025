"""by_roll: the unexplained residual of measurements.csv (184 poses) follows the platform
roll (from home). Written by hexcal diagnose: along it, a bend (two straight lines
meeting at one value) on every leg explains 100 % of the excess over the noise floor on
held-out poses (held-out RMS 27.70 → 10.53 µm once added); the shape's constant is left
to the leg offsets. Loaded as it is, it is that shape; edit it to the physics you
suspect (a formula in place of the shape, fewer parameters, a plausible range), then
pass the file back and add the effect:

    --effects FILE.py --add by_roll
"""

from hexcal.effects import register
from hexcal.effects.explored import ExploredEffect, Shape

#: The lead's shape, as the explorer fitted it (a bend (two straight lines meeting at one value)); legs 1-6 in each row.
SHAPE = Shape.from_dict(
    {'centre': [-0.3095832333522077, -0.3095832333522077, -0.3095832333522077,
                -0.3095832333522077, -0.3095832333522077, -0.3095832333522077],
     'half': [15.491317034197078, 15.491317034197078, 15.491317034197078,
              15.491317034197078, 15.491317034197078, 15.491317034197078],
     'kind': 'hinge',
     'legs': [1, 2, 3, 4, 5, 6],
     'shared': False,
     'split': [1.491129563655736, 0.1838898541923371, 1.491129563655736,
               1.491129563655736, 1.491129563655736, 1.491129563655736]}
)


@register
class ByRoll(ExploredEffect):
    name = "by_roll"
    #: The covariate (hexcal.effects.covariates): platform roll (from home), deg.
    covariate = "roll"
    shape = SHAPE
    physics = (
        "The leg length departs from the model along the platform roll (from home): a"
        " bend (two straight lines meeting at one value) (written by hexcal diagnose;"
        " replace it with the physics you suspect: something that follows the "
        "platform's roll (an encoder cable dragged as it turns, a joint that binds at"
        " an angle))."
    )
    separating_motion = (
        "poses that spread the platform roll (from home) over its whole range"
    )

    # To put the physics you suspect in place of the shape, give the effect its own
    # parameters and basis (docs/effects.md), e.g. one parameter per leg:
    #
    #     def params(self, robot):
    #         return [ParamSpec(f"by_roll.k{leg}", "µm", (-1000.0, 1000.0), 1e-3)
    #                 for leg in range(1, 7)]
    #
    #     def basis(self, data):  # (M, 6, 6) mm per µm
    #         u = covariate_values("roll", data)  # (M, 6) platform roll (from home)
    #         return diagonal(1e-3 * your_formula(u))
    #
    # (import ParamSpec and diagonal from hexcal.effects, covariate_values from
    # hexcal.effects.covariates).
