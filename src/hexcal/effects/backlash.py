"""``backlash``: hysteresis per leg, by the direction in which the leg last moved."""

from __future__ import annotations

import math

import numpy as np

from hexcal.effects.base import (
    Effect,
    EffectData,
    ParamSpec,
    diagonal,
    leg_of,
    per_leg,
    register,
    with_priors,
)

#: The dead band when the encoders' noise is unknown, mm: a reading change smaller than this is
#: not a motion (a clamped leg's readings only jitter).
DEADBAND_MM = 0.02
#: With the encoders' noise σ known, a move is real when the change of a leg's reading exceeds
#: this many standard deviations of that change. The change is the difference of two readings,
#: so its σ is √2·σ_reading and the dead band is 4·√2·σ_reading (5.7 µm for 1 µm encoders): a
#: still leg takes a false move with odds 6e-5 per pose (the two-sided normal tail at 4σ), and a
#: move of twice the dead band is missed with the same odds. 3σ would give a false move every
#: few hundred leg-poses — too many for a session's clamped legs; 5σ would miss moves that
#: still reverse a few µm of play.
DEADBAND_SIGMAS = 4.0
#: Plausible play, mm: 0 … 0.5. A worn or hobby lead screw, a belt or a string drive has a few
#: tenths of a millimetre; a precision ball screw or a direct-drive leg a few µm.
PLAUSIBLE_MM = (0.0, 0.5)
#: Identifiability: the play must be resolved to 10 µm.
RESOLUTION_MM = 0.01


def deadband_for_noise(reading_sigma_mm: float | None) -> float:
    """The dead band (mm) for encoders of reading noise σ (mm): 4·√2·σ; the fallback
    :data:`DEADBAND_MM` when σ is unknown (None or 0)."""
    if not reading_sigma_mm or not math.isfinite(reading_sigma_mm):
        return DEADBAND_MM
    return DEADBAND_SIGMAS * math.sqrt(2.0) * float(reading_sigma_mm)


def deadband_mm(data: EffectData) -> float:
    """The dead band these data are evaluated with: the robot's ``backlash_deadband_mm``
    (stated in robot.json, or set by the fit from the stated encoder noise and carried by the
    calibrated model), else :data:`DEADBAND_MM`."""
    stated = getattr(data.robot, "backlash_deadband_mm", None)
    return float(stated) if stated else DEADBAND_MM


def motion_state(readings: np.ndarray, deadband: float = DEADBAND_MM) -> np.ndarray:
    """(M, 6) in {−1, 0, +1}: the sign of each leg's last motion before each pose (in recording
    order); a leg that did not move keeps its state; 0 until a leg first moves."""
    readings = np.asarray(readings, float)
    state = np.zeros_like(readings)
    for k in range(readings.shape[1]):
        state[:, k] = _leg_state(readings[:, k], deadband)
    return state


def _leg_state(r: np.ndarray, deadband: float) -> np.ndarray:
    """One leg's :func:`motion_state` (M,). A move is a reading more than the dead band from
    the reading at the leg's last move. While the leg moves at every pose that is the previous
    pose's reading, so runs of moves are found whole; only after a pose that did not move is
    the next move searched for, from the reading it must depart from."""
    m = len(r)
    sign = np.zeros(m)
    if m < 2:
        return sign
    jump = np.zeros(m, bool)
    jump[1:] = np.abs(r[1:] - r[:-1]) > deadband  # pose i moved, if pose i − 1 was a move
    stops = np.flatnonzero(~jump)  # the poses where a run of moves ends
    ref, pos = 0, 1  # the reading to depart from; the first pose to test
    while pos < m:
        # The first pose from pos on more than the dead band from the reference reading.
        j, width = -1, 64
        while pos < m:
            hit = np.flatnonzero(np.abs(r[pos : pos + width] - r[ref]) > deadband)
            if len(hit):
                j = pos + int(hit[0])
                break
            pos += width
            width *= 2
        if j < 0:
            break
        sign[j] = 1.0 if r[j] > r[ref] else -1.0
        # The run of moves after it: each pose more than the dead band from the previous.
        end = stops[np.searchsorted(stops, j + 1)] if stops[-1] > j else m
        sign[j + 1 : end] = np.sign(r[j + 1 : end] - r[j : end - 1])
        ref, pos = end - 1, end
    # Each pose keeps the sign of the last move at or before it.
    last = np.maximum.accumulate(np.where(sign != 0, np.arange(m), 0))
    return sign[last]


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
        specs = per_leg("backlash", "beta", "mm", PLAUSIBLE_MM, 1.0, RESOLUTION_MM)
        return with_priors(self.name, specs, robot)

    def basis(self, data: EffectData) -> np.ndarray:
        # A leg extending reads ahead of its length by β/2 when the nut lags: length = reading − β/2.
        return diagonal(-0.5 * motion_state(data.readings, deadband_mm(data)))

    unknown_why = (
        "a leg had not moved yet in the session, so the side of its play it rests on is unknown"
    )

    def unknown(self, data: EffectData) -> np.ndarray | None:
        # State 0: before the leg's first move the session cannot tell which way it last moved.
        state = motion_state(data.readings, deadband_mm(data))
        return state == 0 if (state == 0).any() else None

    def missing(self, data: EffectData) -> str | None:
        state = motion_state(data.readings, deadband_mm(data))
        if not ((state > 0).any(axis=0) & (state < 0).any(axis=0)).any():
            return (
                f"no leg moved in both directions (by more than the dead band, "
                f"{1000 * deadband_mm(data):.3g} µm)"
            )
        return None

    def meaning(self, name: str, value: float, robot) -> str:
        k = leg_of(name)
        if value < 0:
            return (
                f"a negative play in leg {k} is not physical — the direction-dependent residual "
                "has another cause, or the poses are not in recording order"
            )
        return f"{1000 * value:.3g} µm of play in leg {k}'s drive — check its nut, belt and joints"
