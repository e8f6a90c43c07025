"""Where a candidate's score rests on a robot.json key left at its default, say so, and say
what the score becomes if the key were stated otherwise.

The joints' axis effects (``ujoint``, ``balljoint``) read each joint's fixed axis from
robot.json; left out, it defaults to horizontal and across the leg at home (tangential). U-joints
mounted with their fixed axes radial, not written into robot.json, then score low and the
verdict can be ``unexplained`` though the right axes would name the effect. Each such
candidate is scored again with the other common mounting (radial: horizontal, in the plane of
the leg and the vertical), and the two scores are given side by side.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from hexcal.diagnosis.score import Projection
from hexcal.diagnosis.scoring import Candidate, score_candidate
from hexcal.effects.joint_axes import home_legs
from hexcal.estimate.effect_fit import ModelFit, Problem

#: Each effect whose basis rests on a key of robot.json, and the key.
KEYS = {"ujoint": "ujoint_axes", "balljoint": "balljoint_axes"}


@dataclass(frozen=True)
class DefaultNote:
    """A candidate's score at a default key, and what it is with the key stated otherwise."""

    effect: str
    key: str
    alternative: str
    score_default: float
    score_alternative: float

    def text(self) -> str:
        return (
            f"{self.effect}'s score (Δχ² {self.score_default:.1f}) rests on {self.key} left at "
            f"its default (each axis horizontal and across its leg at home); with the axes "
            f"{self.alternative} it is Δχ² {self.score_alternative:.1f}: state {self.key} in "
            "robot.json as the joints are mounted"
        )

    def to_dict(self) -> dict:
        return {
            "effect": self.effect,
            "key": self.key,
            "alternative": self.alternative,
            "score_default": self.score_default,
            "score_alternative": self.score_alternative,
            "text": self.text(),
        }


def radial_axes(problem: Problem, key: str) -> list[list[float]]:
    """(6, 3) each joint's axis horizontal and in the plane of its leg and the vertical at
    home (radial), in the frame ``key`` is given in (the base's, or the platform's)."""
    d = problem.design
    n0, rot = home_legs(d, problem.data.a, problem.data.b)
    if key == "balljoint_axes":
        n0 = n0 @ rot
    flat = n0 * np.array([1.0, 1.0, 0.0])
    norm = np.linalg.norm(flat, axis=1, keepdims=True)
    flat = np.where(norm > 1e-9, flat / np.maximum(norm, 1e-300), [[1.0, 0.0, 0.0]])
    return flat.tolist()


def default_notes(
    problem: Problem, fit: ModelFit, candidates: list[Candidate]
) -> list[DefaultNote]:
    """A note for every available candidate of :data:`KEYS` whose key robot.json leaves out."""
    out = []
    for c in candidates:
        key = KEYS.get(c.effect)
        if key is None or not c.available or getattr(problem.design, key, None) is not None:
            continue
        design = problem.design.model_copy(update={key: radial_axes(problem, key)})
        other = replace(
            problem, design=design, data=replace(problem.data, robot=design), _bases={}, _missing={}
        )
        alt = score_candidate(other, fit, c.effect, Projection.of(other, fit))
        out.append(DefaultNote(c.effect, key, "radial", c.score, alt.score))
    return out
