"""Hidden effects for the simulator: the same effect units, with true parameter values.

The simulator finds readings r with ``r + offset + Σ contribution(r) = true length``, so a
session simulated with an effect is what the model with that effect describes — exactly, or,
for an effect linearised from an exact law (the joints' axis offsets), by that law
(:meth:`~hexcal.effects.base.Effect.true_contribution`). Any registered effect can be hidden,
the catalogue's or one loaded from outside it.
"""

from __future__ import annotations

import numpy as np

from hexcal.effects.base import EffectData, get_effect
from hexcal.model.robot import Robot
from hexcal.sim.simulate import LengthEffect, PoseContext

#: Length of a typical simulated session, h (:class:`hexcal.sim.session_sim.SessionPlan`: 184 poses
#: 8 to 20 s apart), over which a realistic drift is sized.
TYPICAL_SESSION_H = 184 * 14.0 / 3600.0


#: mm: the hidden backlash's dead band on the simulator's noise-free readings.
TRUE_PLAY_DEADBAND_MM = 1e-4


def effect_hook(
    name: str, values: np.ndarray, truth: Robot, extras: dict | None = None
) -> LengthEffect:
    """A simulator hook adding effect ``name`` with ``values`` (spec units) to the true robot;
    ``extras``: the effects' data extras (:attr:`~hexcal.effects.base.EffectData.extras`, e.g.
    a drift's time origin, :data:`hexcal.effects.drift.T_MID`)."""
    eff = get_effect(name)
    values = np.asarray(values, float)
    n = len(eff.params(truth))
    if values.shape != (n,):
        raise ValueError(
            f"effect {name!r} takes {n} values ({[s.name for s in eff.params(truth)]}), got {values.shape}"
        )

    if name == "backlash" and truth.backlash_deadband_mm is None:
        # The simulator hands the hook noise-free readings: every real move, however small,
        # takes up the play. The dead band is the fit's defence against noise, not physics.
        truth = truth.model_copy(update={"backlash_deadband_mm": TRUE_PLAY_DEADBAND_MM})

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        data = EffectData(
            readings,
            ctx.position,
            ctx.rotation,
            ctx.t,
            ctx.temperature,
            truth,
            truth.a,
            truth.b,
            extras=dict(extras or {}),
        )
        return eff.true_contribution(data, values)

    hook.__name__ = f"hidden_{name}"
    return hook


def realistic_values(
    name: str, rng: np.random.Generator, truth: Robot, scale: float = 1.0
) -> np.ndarray:
    """Random true values at a realistic size (``scale`` < 1 for sizes near detection); an
    effect from outside the catalogue gives its own (:meth:`Effect.typical_values`)."""
    sign = rng.choice([-1.0, 1.0], 6)
    if name == "offset":
        return scale * sign * rng.uniform(0.2, 1.0, 6)
    if name == "gain":
        return scale * sign * rng.uniform(300.0, 1000.0, 6)  # ppm
    if name == "backlash":
        return scale * rng.uniform(0.02, 0.06, 6)  # mm
    if name == "thermal":
        return scale * rng.uniform(15.0, 25.0, 1)  # ppm/K: steel to aluminium
    if name == "compliance":
        return scale * rng.uniform(1.0, 3.0, 1)  # µm/N
    if name == "leadscrew":
        amp = scale * rng.uniform(0.005, 0.015, 6)
        phase = rng.uniform(0, 2 * np.pi, 6)
        return np.column_stack([amp * np.cos(phase), amp * np.sin(phase)]).ravel()
    if name == "drift":
        # 100–200 µm over a typical simulated session (184 poses, 8–20 s apart: about 43 min),
        # in a random direction: a tracker warming up, or its stand settling.
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        return scale * rng.uniform(100.0, 200.0) / TYPICAL_SESSION_H * direction  # µm/h
    if name in ("ujoint", "balljoint"):
        # Every joint's axes 1 mm apart (a hobby or printed joint), the side drawn per leg.
        return scale * sign * 1.0  # mm
    typical = get_effect(name).typical_values(rng, truth)
    if typical is not None:
        return scale * np.asarray(typical, float)
    raise ValueError(
        f"effect {name!r} gives no typical size (its typical_values method): give its values "
        "(hexcal simulate --effect-values)"
    )


def zero_jump_hook(leg: int, first: int, size_mm: float) -> LengthEffect:
    """Leg ``leg`` (1-based) reads ``size_mm`` longer from the ``first``-th pose of the session
    on (0-based, recording order): a zero step as the ``zero_step`` effect describes it (lost
    counts, a re-home). The hook sees the whole session's times at once, so the step's time
    is that pose's."""

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        out = np.zeros_like(readings)
        t = np.asarray(ctx.t, float)
        out[:, leg - 1] = -size_mm * (t >= t[first])
        return out

    hook.__name__ = "hidden_zero_step"
    return hook
