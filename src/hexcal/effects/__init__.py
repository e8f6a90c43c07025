"""The catalogue of physical effects beyond the ideal geometry.

An effect is one small unit (a subclass of :class:`~hexcal.effects.base.Effect`, registered with
:func:`~hexcal.effects.base.register`): its parameters with units and plausible ranges, its
contribution to the predicted leg length, what it needs from the data, one sentence of physics,
and the motion that separates it from the geometry. Importing this package registers the
catalogue; adding an effect is one new module and one import line below.
"""

from hexcal.effects import (  # noqa: F401
    backlash,
    compliance,
    drift,
    gain,
    leadscrew,
    offset,
    thermal,
    zero_step,
)
from hexcal.effects.base import (
    CATALOGUE,
    Effect,
    EffectData,
    ParamSpec,
    diagonal,
    get_effect,
    register,
)

__all__ = [
    "CATALOGUE",
    "Effect",
    "EffectData",
    "ParamSpec",
    "diagonal",
    "get_effect",
    "register",
]
