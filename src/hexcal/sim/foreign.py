"""Effects outside the catalogue, for testing that the diagnosis says ``unexplained`` instead of
forcing a catalogue effect onto them. They are simulator hooks only, never registered."""

from __future__ import annotations

import numpy as np

from hexcal.sim.simulate import LengthEffect, PoseContext


def local_dent(leg: int, axis: int, size_mm: float, home: np.ndarray) -> LengthEffect:
    """Leg ``leg`` (1-based) reads ``size_mm`` long whenever the platform is on the positive
    side of its home position along ``axis`` (0 x, 1 y, 2 z): a dent in one rail, a cable that
    pulls in one region. Structured, local, and no catalogue effect has that shape."""

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        out = np.zeros_like(readings)
        out[:, leg - 1] = size_mm * (ctx.position[:, axis] > home[axis])
        return out

    return hook
