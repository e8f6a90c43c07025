"""``backlash``: hysteresis per leg, by the direction in which the leg last moved."""

from __future__ import annotations

import numpy as np

from hexcal.effects.base import Effect, EffectData, ParamSpec, diagonal, per_leg, register

#: A reading change smaller than this is not a motion (mm): a clamped leg's readings only jitter.
DEADBAND_MM = 0.02


def motion_state(readings: np.ndarray, deadband: float = DEADBAND_MM) -> np.ndarray:
    """(M, 6) in {−1, 0, +1}: the sign of each leg's last motion before each pose (in recording
    order); a leg that did not move keeps its state; 0 until a leg first moves."""
    state = np.zeros_like(readings)
    current = np.zeros(readings.shape[1])
    last = readings[0].copy()
    for m in range(len(readings)):
        step = readings[m] - last
        moved = np.abs(step) > deadband
        current = np.where(moved, np.sign(step), current)
        last = np.where(moved, readings[m], last)
        state[m] = current
    return state


@register
class Backlash(Effect):
    name = "backlash"
    physics = (
        "Play in the screw and nut lets the reading lead or lag the length by half the backlash, "
        "depending on the direction the leg last moved."
    )
    needs = ("motion history (poses in recording order)",)
    separating_motion = "each pose approached alternately from longer and from shorter leg lengths"

    def params(self, robot) -> list[ParamSpec]:
        return per_leg("backlash", "beta", "mm", (0.0, 0.2))

    def basis(self, data: EffectData) -> np.ndarray:
        # A leg extending reads ahead of its length by β/2 when the nut lags: length = reading − β/2.
        return diagonal(-0.5 * motion_state(data.readings))

    def missing(self, data: EffectData) -> str | None:
        state = motion_state(data.readings)
        if not ((state > 0).any(axis=0) & (state < 0).any(axis=0)).any():
            return "no leg moved in both directions"
        return None
