"""``drift``: the tracker's frame (or the structure under it) translating steadily over the
session — a property of the session, not of the robot."""

from __future__ import annotations

import numpy as np

from hexcal.effects.base import Effect, EffectData, ParamSpec, register, with_priors

#: µm/h → mm/s, the model's internal unit of a drift velocity.
UM_PER_H = 1e-3 / 3600.0
#: Plausible drift, µm/h per axis. A warmed-up tracker on a stable stand, in a room that holds
#: its temperature within a few kelvin, drifts by tens to a few hundred µm over an hour (its
#: warm-up, the stand's and the floor's expansion); 1 mm/h or more is not a drift but a tracker
#: or a robot that moved (knocked, re-seated), which a linear term only pretends to describe.
PLAUSIBLE_UM_PER_H = (-1000.0, 1000.0)
#: Identifiability: the data must resolve a drift to this, µm/h (about 35 µm over a typical
#: 43-minute session: three times the tracker's noise).
RESOLUTION_UM_PER_H = 50.0
#: A session whose poses span less time than this (s) cannot show a drift: at the plausible
#: limit it is under 20 µm, the size of the tracker's own noise.
MIN_SPAN_S = 60.0


#: EffectData.extras key: the middle of the whole session's time span, s, for data holding only
#: some of its poses (the outliers set aside), so that their drift is reckoned from the same time.
T_MID = "t_mid_s"


def time_from_middle(data: EffectData) -> np.ndarray:
    """(M,) s from the middle of the session's time span (centred: the drift then leaves the
    mean pose where it is, and its constant part stays with the base points)."""
    t = np.asarray(data.t, float)
    mid = data.extras.get(T_MID)
    return t - (0.5 * (t.min() + t.max()) if mid is None else float(mid))


@register
class Drift(Effect):
    name = "drift"
    physics = (
        "The tracker's frame (or the structure under it) translates steadily over the session, "
        "so each leg's length computed from the tracked pose is off by n_k·v·(t − t_mid), n_k "
        "the leg's unit vector and v the drift velocity."
    )
    needs = ("the time of each pose",)
    separating_motion = (
        "poses spread over the session's time, revisiting the same workspace (early and late "
        "poses at the same places)"
    )
    uses_geometry = True
    #: A property of the session, not of the robot: fitted to calibrate from this session, but
    #: not carried into the calibrated model (another session drifts otherwise).
    of_the_session = True

    def params(self, robot) -> list[ParamSpec]:
        specs = [
            ParamSpec(f"drift.v{axis}", "µm/h", PLAUSIBLE_UM_PER_H, UM_PER_H, RESOLUTION_UM_PER_H)
            for axis in "xyz"
        ]
        return with_priors(self.name, specs, robot)

    def basis(self, data: EffectData) -> np.ndarray:
        v = data.leg_vectors
        n = v / np.linalg.norm(v, axis=-1, keepdims=True)
        return n * (time_from_middle(data) * UM_PER_H)[:, None, None]

    def meaning(self, name: str, value: float, robot) -> str:
        return (
            "a drift this fast is no tracker warming up: the tracker or the robot moved during "
            "the session (a knock, a re-seated stand) — look at the residual against time and "
            "record the session again"
        )

    def missing(self, data: EffectData) -> str | None:
        t = np.asarray(data.t, float)
        span = float(np.ptp(t)) if len(t) else 0.0
        if not np.isfinite(span) or span < MIN_SPAN_S:
            return f"the poses span {span:.0f} s: too short a time to show a drift"
        return None
