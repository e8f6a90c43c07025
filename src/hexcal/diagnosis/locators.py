"""Effects whose places are searched for before they are fitted, and the one function that
locates them — for ``hexcal diagnose`` and ``hexcal calibrate`` alike.

Some effects' parameters sit at places the linear fit cannot find: ``zero_step``'s steps happen
at times (:mod:`hexcal.diagnosis.changepoint`). Each such effect has a :class:`Locator` in
:data:`LOCATORS`, keyed by its name: the search (at the model without the effect, against the
session's robust noise level), how its findings are given to the problem (the robot.json key
that then holds them), and what to say when nothing is found. :func:`locate_effects` runs them:
the diagnosis calls it when such an effect is in the model on a fresh session, the calibration
(:func:`hexcal.app.workflow.calibrate_model`) whenever ``--add`` names one, so that
``diagnose --auto --out`` and ``calibrate --add`` with the same effects fit the same places and
write the same model. Another such effect is one more entry.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from hexcal.diagnosis.changepoint import locate, located, search
from hexcal.diagnosis.outliers import robust_level
from hexcal.estimate.effect_fit import ModelFit, Problem, fit_model
from hexcal.model.robot import Robot


@dataclass(frozen=True)
class Locator:
    """How one effect's places are found: ``search(problem, fit, level)`` → the findings at
    ``fit`` (the model without the effect; ``level`` the noise level s²), ``locate(problem,
    findings)`` gives them to the problem's design, ``located(problem)`` says whether its
    design holds them (found or stated), ``key`` is the robot.json key that holds them, and
    ``none_found`` the refusal when the search finds nothing."""

    search: Callable[[Problem, ModelFit, float], list[Any]]
    locate: Callable[[Problem, list[Any]], None]
    located: Callable[[Problem], bool]
    key: str
    none_found: str


LOCATORS: dict[str, Locator] = {
    "zero_step": Locator(
        search,
        locate,
        located,
        "zero_steps",
        "zero_step: no change of a leg's zero is found in this session (the change-point "
        "search on each leg's residual in recording order finds no step beyond its "
        "threshold); leave zero_step out, or state zero_steps in robot.json",
    ),
}


def to_locate(problem: Problem, effects: Sequence[str]) -> list[str]:
    """The effects of ``effects`` that are searched for and not yet located in ``problem``."""
    return [e for e in effects if e in LOCATORS and not LOCATORS[e].located(problem)]


def locate_effects(problem: Problem, effects: Sequence[str]) -> None:
    """Locate every effect of ``effects`` that needs it (see the module docstring): fit the
    model without them, search each, give the findings to ``problem``. Raises ValueError with
    the effect's own message when its search finds nothing."""
    pending = to_locate(problem, effects)
    if not pending:
        return
    base = tuple(e for e in effects if e not in pending)
    fit = fit_model(problem, base, cross_validate=False)
    level = robust_level(problem, fit)
    for name in pending:
        loc = LOCATORS[name]
        loc.locate(problem, loc.search(problem, fit, level))
        if not loc.located(problem):
            raise ValueError(loc.none_found)


def carry_located(source: Robot, target: Robot, effects: Sequence[str]) -> Robot:
    """``target`` with the places of ``effects`` that ``source`` holds (its located keys):
    a diagnosis' findings handed to the calibration of its model."""
    update = {}
    for name in effects:
        loc = LOCATORS.get(name)
        if loc is not None and getattr(source, loc.key, None):
            update[loc.key] = getattr(source, loc.key)
    return target.model_copy(update=update) if update else target


def locate_candidates(
    problem: Problem, fit: ModelFit, level: float, effects: Sequence[str]
) -> dict[str, list[Any]]:
    """Search for every located effect not in the model ``effects`` at its ``fit`` (noise
    level s² ``level``) and give what is found to ``problem``, so that each is scored as a
    candidate at its places: {effect: its findings}."""
    found = {}
    for name, loc in LOCATORS.items():
        if name not in effects:
            found[name] = loc.search(problem, fit, level)
            loc.locate(problem, found[name])
    return found
