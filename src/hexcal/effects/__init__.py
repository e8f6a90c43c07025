"""The catalogue of physical effects beyond the ideal geometry, and the public Effect API.

An effect is one small unit (a subclass of :class:`Effect`, registered with :func:`register`):
its parameters with units and plausible ranges (:class:`ParamSpec`), its contribution to the
predicted leg length as a basis over the poses (:class:`EffectData` → (M, 6, p) mm, built with
:func:`diagonal` when each leg has its own parameter), what it needs from the data, one sentence
of physics, and the motion that separates it from the geometry. Those five names are the Effect
API, version :data:`API_VERSION`, documented in docs/effects.md.

Importing this package registers hexcal's catalogue (one module each, below), then the effects
of installed packages (entry-point group ``hexcal.effects``); :func:`load_file` registers those
of a Python file the user names (``--effects FILE.py``). See :mod:`hexcal.effects.plugins`.
"""

from hexcal.effects import (  # noqa: F401
    backlash,
    balljoint,
    compliance,
    drift,
    frame_step,
    gain,
    leadscrew,
    offset,
    thermal,
    ujoint,
    zero_step,
)
from hexcal.effects.base import (
    API_VERSION,
    CATALOGUE,
    Effect,
    EffectData,
    EffectError,
    EffectSource,
    ParamSpec,
    diagonal,
    get_effect,
    register,
)
from hexcal.effects.plugins import load_file, load_installed

load_installed()

__all__ = [
    "API_VERSION",
    "CATALOGUE",
    "Effect",
    "EffectData",
    "EffectError",
    "EffectSource",
    "ParamSpec",
    "diagonal",
    "get_effect",
    "load_file",
    "register",
]
