"""Effects whose places are searched for before they are fitted, and the one function that
locates them — for ``hexcal diagnose`` and ``hexcal calibrate`` alike.

Some effects' parameters sit at places the linear fit cannot find: ``zero_step``'s steps and
``frame_step``'s move happen at times (:mod:`hexcal.diagnosis.changepoint`,
:mod:`hexcal.diagnosis.frame_search`). Each such effect has a :class:`Locator` in
:data:`LOCATORS`, keyed by its name: how its findings are given to the problem (the robot.json
key that then holds them), whether the problem holds them, and what to say when nothing is
found. The searches run together (:func:`search_events`, at the model without the effects,
against the session's robust noise level), because they decide between each other: a move of
the tracker is looked for first, and a leg's zero step counts only away from it (the legs that
changed with the move changed with it, not alone) and where it is significant beyond a smooth
curve of that leg's residual in time (uneven heating is a curve). :func:`locate_effects` runs them:
the diagnosis calls it when such an effect is in the model on a fresh session, the calibration
(:func:`hexcal.app.workflow.calibrate_model`) whenever ``--add`` names one, so that
``diagnose --auto --out`` and ``calibrate --add`` with the same effects fit the same places and
write the same model. Another such effect is one more entry.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hexcal.diagnosis.changepoint import locate, located, search
from hexcal.diagnosis.frame_search import leg_step_beyond_smooth, locate_frame, search_frame
from hexcal.diagnosis.outliers import robust_level
from hexcal.diagnosis.pose_products import PoseProducts
from hexcal.effects.frame_step import frame_steps_of
from hexcal.estimate.effect_fit import ModelFit, Problem, fit_model
from hexcal.model.robot import Robot

#: A leg's zero step within this many poses of a move of the tracker is the move's.
FRAME_POSES = 3


@dataclass(frozen=True)
class Locator:
    """How one effect's places are kept (its search is :func:`search_events`'s):
    ``locate(problem, findings)`` gives them to the problem's design, ``located(problem)`` says whether its
    design holds them (found or stated), ``key`` is the robot.json key that holds them, and
    ``none_found`` the refusal when the search finds nothing."""

    locate: Callable[[Problem, list[Any]], None]
    located: Callable[[Problem], bool]
    key: str
    none_found: str


LOCATORS: dict[str, Locator] = {
    "frame_step": Locator(
        lambda p, found: locate_frame(p, found[0] if found else None),
        lambda p: bool(frame_steps_of(p.design)),
        "frame_steps",
        "frame_step: no rigid move of the tracker is found in this session (the search for "
        "every leg changing together at one pose finds none beyond its threshold); leave "
        "frame_step out, or state frame_steps in robot.json",
    ),
    "zero_step": Locator(
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
    found = search_events(problem, fit, robust_level(problem, fit), base)
    for name in pending:
        loc = LOCATORS[name]
        loc.locate(problem, found.get(name, []))
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
    found = search_events(problem, fit, level, effects)
    for name, findings in found.items():
        LOCATORS[name].locate(problem, findings)
    return found


def search_events(
    problem: Problem, fit: ModelFit, level: float, effects: Sequence[str]
) -> dict[str, list[Any]]:
    """The events in time of every located effect not in ``effects`` (see the module
    docstring), at ``fit`` and noise level s² ``level``: {effect: its findings}."""
    products = PoseProducts(fit, level)
    found: dict[str, list[Any]] = {}
    frame_rows: list[int] = []
    if "frame_step" not in effects:
        frame = search_frame(problem, fit, level, products)
        found["frame_step"] = [] if frame is None else [frame]
        frame_rows = [] if frame is None else [frame.index]
    else:
        t = np.asarray(problem.meas.t, float)
        frame_rows = [int(np.searchsorted(t, s.t_s)) for s in frame_steps_of(problem.design)]
    if "zero_step" not in effects:
        found["zero_step"] = [
            c
            for c in search(problem, fit, level)
            if leg_step_beyond_smooth(products, problem, c.leg, c.index) > c.threshold
            and all(abs(c.index - row) > FRAME_POSES for row in frame_rows)
        ]
    return found
