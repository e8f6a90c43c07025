"""``frame_step``: the tracker (or the robot's base under it) moving rigidly once during the
session — knocked, re-seated — a property of the session, not of the robot.

From that pose on every pose is measured in a frame moved by a small translation v and
rotation ω, so each leg's length computed from the tracked pose is off by
n_k·(v + ω × p_k), n_k the leg's unit vector and p_k its platform joint's position: six legs
changing together at one pose in the pattern of a rigid move, where a leg's lost counts
change one leg alone (``zero_step``). The step's time is located first, by the diagnosis'
search (:mod:`hexcal.diagnosis.frame_search`), or stated in robot.json (``frame_steps``).
"""

from __future__ import annotations

import numpy as np

from hexcal.effects.base import Effect, EffectData, ParamSpec, register, with_priors

#: Plausible move: ± 10 mm and ± 0.1 rad (a knocked stand, a re-seated tracker).
PLAUSIBLE_UM = (-10_000.0, 10_000.0)
PLAUSIBLE_URAD = (-100_000.0, 100_000.0)
#: Identifiability: the data must resolve a move to 10 µm and 50 µrad.
RESOLUTION_UM = 10.0
RESOLUTION_URAD = 50.0


def frame_steps_of(robot) -> list:
    """The robot's frame steps (``frame_steps``), in time order."""
    return sorted(getattr(robot, "frame_steps", None) or [], key=lambda s: s.t_s)


def rigid_move_basis(data: EffectData) -> np.ndarray:
    """(M, 6, 6) mm per unit: each leg's length change under a move of the measuring frame by
    a translation (µm, columns 0-2) and a rotation (µrad, columns 3-5) about its origin."""
    v = data.leg_vectors
    n = v / np.linalg.norm(v, axis=-1, keepdims=True)
    p = data.position[:, None, :] + np.einsum("mij,kj->mki", data.rotation, data.b)
    return np.concatenate([1e-3 * n, 1e-6 * np.cross(p, n)], axis=-1)


@register
class FrameStepEffect(Effect):
    name = "frame_step"
    physics = (
        "The tracker (or the robot's base under it) moves rigidly once during the session: from "
        "then on every pose is measured in a frame moved by v and ω, so each leg's length is off "
        "by n_k·(v + ω × p_k)."
    )
    needs = (
        "the poses in recording order with their times, and the move's time: located by "
        "hexcal diagnose's search, or frame_steps in robot.json",
    )
    separating_motion = (
        "poses before and after the move that revisit the same places (repeat the first poses "
        "at the end), and a tracker fixed to a stand nobody touches"
    )
    uses_geometry = True
    of_the_session = True
    #: One time searched for every six parameters (ΔBIC counts it as one more parameter).
    searched_params = 1.0 / 6.0

    def params(self, robot) -> list[ParamSpec]:
        specs = []
        for j, _ in enumerate(frame_steps_of(robot), start=1):
            specs += [
                ParamSpec(f"frame_step.v{axis}{j}", "µm", PLAUSIBLE_UM, 1e-3, RESOLUTION_UM)
                for axis in "xyz"
            ]
            specs += [
                ParamSpec(f"frame_step.w{axis}{j}", "µrad", PLAUSIBLE_URAD, 1e-6, RESOLUTION_URAD)
                for axis in "xyz"
            ]
        return with_priors(self.name, specs, robot)

    def basis(self, data: EffectData) -> np.ndarray:
        steps = frame_steps_of(data.robot)
        move = rigid_move_basis(data)
        t = np.asarray(data.t, float)
        return np.concatenate(
            [move * (t >= s.t_s)[:, None, None] for s in steps] or [np.zeros((len(t), 6, 0))],
            axis=-1,
        )

    def missing(self, data: EffectData) -> str | None:
        steps = frame_steps_of(data.robot)
        if not steps:
            return "no move of the tracker located (or stated: frame_steps)"
        t = np.asarray(data.t, float)
        for s in steps:
            after = int((t >= s.t_s).sum())
            if after == 0 or after == len(t):
                return (
                    f"the frame step at t {s.t_s:g} s has no poses on one side of it "
                    "(robot.json frame_steps is of another session?)"
                )
        return None

    def meaning(self, name: str, value: float, robot) -> str:
        return (
            "a move this large is no knock: check that the table's rows are in recording order "
            "and that the tracker tracked the same body throughout"
        )
