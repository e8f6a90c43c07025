"""by_force: the unexplained residual of measurements.csv (184 poses) follows the axial leg
force holding the platform's weight. Written by hexcal diagnose: along it, a step at its
sign change on every leg explains 94 % of the excess over the noise floor on held-out
poses (held-out RMS 13.51 → 10.49 µm once added); the shape's constant is left to the
leg offsets. Loaded as it is, it is that shape; edit it to the physics you suspect (a
formula in place of the shape, fewer parameters, a plausible range), then pass the file
back and add the effect:

    --effects FILE.py --add by_force
"""

from hexcal.effects import register
from hexcal.effects.explored import ExploredEffect, Shape

#: The lead's shape, as the explorer fitted it (a step at its sign change); legs 1-6 in each row.
SHAPE = Shape.from_dict(
    {'kind': 'sign', 'legs': [1, 2, 3, 4, 5, 6], 'shared': False}
)


@register
class ByForce(ExploredEffect):
    name = "by_force"
    #: The covariate (hexcal.effects.covariates): axial leg force holding the platform's weight, N.
    covariate = "force"
    shape = SHAPE
    physics = (
        "The leg length departs from the model along the axial leg force holding the "
        "platform's weight: a step at its sign change (written by hexcal diagnose; "
        "replace it with the physics you suspect: play in a leg's joints, taken up "
        "one way or the other as its load reverses)."
    )
    separating_motion = (
        "poses that spread the axial leg force holding the platform's weight over its"
        " whole range"
    )

    # To put the physics you suspect in place of the shape, give the effect its own
    # parameters and basis (docs/effects.md), e.g. one parameter per leg:
    #
    #     def params(self, robot):
    #         return [ParamSpec(f"by_force.k{leg}", "µm", (-1000.0, 1000.0), 1e-3)
    #                 for leg in range(1, 7)]
    #
    #     def basis(self, data):  # (M, 6, 6) mm per µm
    #         u = covariate_values("force", data)  # (M, 6) axial leg force holding the platform's weight
    #         return diagonal(1e-3 * your_formula(u))
    #
    # (import ParamSpec and diagonal from hexcal.effects, covariate_values from
    # hexcal.effects.covariates).
