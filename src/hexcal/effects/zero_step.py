"""``zero_step``: one leg's encoder zero changing once during the session (lost counts, a
re-home) — a property of the session, not of the robot.

The step's time is not a parameter of the linear fit: it is located first, by the diagnosis'
change-point search on each leg's residual in recording order
(:mod:`hexcal.diagnosis.changepoint`), or stated in robot.json (``zero_steps``), and the
effect's parameters are the steps' sizes at those times.
"""

from __future__ import annotations

import numpy as np

from hexcal.effects.base import Effect, EffectData, ParamSpec, leg_of, register, with_priors

#: Plausible size of a step, µm: ± 10 mm, the offsets' own range (a lost belt tooth or a
#: missed index pulse is a few mm; lost counts of a fine encoder a few µm).
PLAUSIBLE_UM = (-10_000.0, 10_000.0)
#: Identifiability: a step must be resolved to 10 µm.
RESOLUTION_UM = 10.0


def steps_of(robot) -> list:
    """The robot's zero steps (``zero_steps``), by leg."""
    return sorted(getattr(robot, "zero_steps", None) or [], key=lambda s: s.leg)


@register
class ZeroStepEffect(Effect):
    name = "zero_step"
    physics = (
        "A leg's encoder zero changes once during the session (lost counts, a missed index "
        "pulse, a re-home): from then on it reads δ_k longer for the same length."
    )
    needs = (
        "the poses in recording order with their times, and the step's time: located by "
        "hexcal diagnose's change-point search, or zero_steps in robot.json",
    )
    separating_motion = (
        "poses before and after the change that reach the same leg lengths (free poses spread "
        "over the session, or repeat the first poses at the end)"
    )
    #: A property of the session: the calibrated model keeps the zero the session started
    #: with (the robot as homed), not the step.
    of_the_session = True
    #: Each parameter's time was found by a search over the session's poses: the evidence
    #: (ΔBIC) counts it as one more parameter.
    searched_params = 1

    def params(self, robot) -> list[ParamSpec]:
        specs = [
            ParamSpec(f"zero_step.d{s.leg}", "µm", PLAUSIBLE_UM, 1e-3, RESOLUTION_UM)
            for s in steps_of(robot)
        ]
        return with_priors(self.name, specs, robot)

    def basis(self, data: EffectData) -> np.ndarray:
        steps = steps_of(data.robot)
        out = np.zeros((len(data), 6, len(steps)))
        t = np.asarray(data.t, float)
        for j, s in enumerate(steps):
            # A leg that reads δ longer from t_s on: length = reading + offset − δ after it
            # (δ in µm, the basis in mm per µm).
            out[:, s.leg - 1, j] = -1e-3 * (t >= s.t_s)
        return out

    def missing(self, data: EffectData) -> str | None:
        steps = steps_of(data.robot)
        if not steps:
            return "no change of a leg's zero located (or stated: zero_steps)"
        t = np.asarray(data.t, float)
        for s in steps:
            after = int((t >= s.t_s).sum())
            if after == 0 or after == len(t):
                return (
                    f"leg {s.leg}'s zero step at t {s.t_s:g} s has no poses on one side of it "
                    "(robot.json zero_steps is of another session?)"
                )
        return None

    def meaning(self, name: str, value: float, robot) -> str:
        return (
            f"leg {leg_of(name)}'s zero moving by {abs(value) / 1000:.3g} mm is no lost count — "
            "check the encoder's cable and index, and that the table's rows are in recording order"
        )
