"""The keys robot.json's ``plausible`` may use, judged against the effect catalogue.

A robot file is read by the model stage, which knows nothing of effects; the readers above it
(:func:`hexcal.estimate.model_file.parse_model`, :func:`hexcal.procedure.session.load_session`) call
:func:`check_priors` so that a misspelt key is refused with the file's name and the known keys.
"""

from __future__ import annotations

from hexcal.effects.base import CATALOGUE
from hexcal.model.robot import Robot


def prior_names(robot: Robot) -> set[str]:
    """The keys robot.json's ``plausible`` may use for this robot: every catalogue effect and
    every parameter's full name (``compliance.c`` with ``platform_mass_kg``, else
    ``compliance.cm``)."""
    names = set(CATALOGUE)
    for eff in CATALOGUE.values():
        names.update(s.name for s in eff.params(robot))
    return names


def known_text(robot: Robot) -> str:
    """The known ``plausible`` keys, one group per effect: ``gain (gain.g1 … gain.g6)``."""
    parts = []
    for name in sorted(CATALOGUE):
        specs = [s.name for s in CATALOGUE[name].params(robot)]
        inner = " … ".join([specs[0], specs[-1]]) if len(specs) > 2 else ", ".join(specs)
        parts.append(f"{name} ({inner})" if inner else name)
    return ", ".join(parts)


def check_priors(robot: Robot, where: str) -> None:
    """Refuse (ValueError naming ``where`` and the field) a ``plausible`` key that is neither a
    catalogue effect nor one of this robot's parameters."""
    table = robot.plausible or {}
    known = prior_names(robot)
    unknown = [k for k in table if k not in known]
    if unknown:
        hint = ""
        if "compliance.c" in unknown and not robot.platform_mass_kg:
            hint = " (without platform_mass_kg the compliance parameter is compliance.cm, c·m)"
        raise ValueError(
            f"{where}: field plausible: unknown effect or parameter "
            f"{', '.join(map(repr, unknown))}; known: {known_text(robot)}{hint}"
        )
