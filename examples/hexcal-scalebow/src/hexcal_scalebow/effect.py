"""``scalebow``: an encoder whose scale error grows quadratically along the stroke.

An example of an effect from outside hexcal's catalogue, written against the public Effect API
only (``from hexcal.effects import ...``). This file is self-contained: it works installed (the
package's entry point in the group ``hexcal.effects``) and as ``hexcal ... --effects effect.py``.

**Physics.** A leg's length is read from a scale (a lead screw's turns, a glass or magnetic
scale) whose error is not uniform along the travel: a screw ground with a progressive lead error,
a scale bonded onto a bowed surface, a screw warmer in its middle than at its ends. The linear
part of such an error is a scale error (``gain``) and its constant part an offset; what is left
is, to lowest order, quadratic about the leg's home reading ρ₀:

    ΔL_k = q_k · ((ρ_k − ρ₀_k) / 50 mm)²          (q_k in µm: the error 50 mm from home)

and the model's contribution (added to ``reading + offset`` to give the geometric length) is
``+ΔL_k``: the leg is longer than its reading says where ``q_k`` > 0. ρ₀_k is the reading at the
robot's home pose, from the model's own geometry (robot.json ``home``), so a calibrated model
evaluates the effect as the fit did.

**Sizes.** ISO 3408-3 allows a positioning ball screw of class 5 a travel deviation of about
20 µm over 300 mm; a rolled screw (class 7–10) 50–200 µm. The curved part over a hexapod leg's
stroke is a fraction of that: 5–15 µm at 50 mm from home is what :meth:`typical_values` draws.

**What separates it.** Each leg driven over its whole stroke, its readings spread on both sides
of home: a quadratic is then told from the offset (constant) and from a gain (linear).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.effects import Effect, EffectData, ParamSpec, diagonal, register

#: The distance from home at which the parameter is the error, mm.
REACH_MM = 50.0
#: Plausible error at that distance, µm: a rolled screw's curvature stays within this.
PLAUSIBLE_UM = (-200.0, 200.0)
#: The data must resolve each q_k to this, µm: a third of the 12 µm a class-7 screw's curved
#: part reaches 50 mm from home. A standard simulated session resolves it to about 2 µm.
RESOLUTION_UM = 4.0


def home_readings(data: EffectData) -> np.ndarray:
    """(6,) mm: each leg's reading at the robot's home pose, at the evaluation geometry."""
    home = data.robot.home
    rot = Rotation.from_quat(home.quaternion, scalar_first=True).as_matrix()
    legs = np.asarray(home.position, float) + data.b @ rot.T - data.a
    return np.linalg.norm(legs, axis=1) - data.robot.offsets


@register
class ScaleBow(Effect):
    name = "scalebow"
    physics = (
        "A leg's scale error grows quadratically along its travel (a screw's progressive lead "
        "error, a scale on a bowed surface): ΔL_k = q_k·((ρ_k − ρ₀_k)/50 mm)², ρ₀_k the reading "
        "at home."
    )
    separating_motion = "each leg driven over its whole stroke, on both sides of its home reading"
    # The home readings come from the geometry and the offsets: evaluate at the fitted ones.
    uses_geometry = True

    def params(self, robot) -> list[ParamSpec]:
        return [
            ParamSpec(f"scalebow.q{k}", "µm", PLAUSIBLE_UM, 1e-3, RESOLUTION_UM)
            for k in range(1, 7)
        ]

    def basis(self, data: EffectData) -> np.ndarray:
        reach = (data.readings - home_readings(data)) / REACH_MM
        return diagonal(reach**2 * 1e-3)  # mm per µm of q_k

    def meaning(self, name: str, value: float, robot) -> str:
        return (
            f"leg {name[-1]}'s reading is off by {abs(value):.3g} µm 50 mm from home — check "
            "its screw or scale, and that its readings are in mm"
        )

    def typical_values(self, rng: np.random.Generator, robot) -> np.ndarray:
        return rng.choice([-1.0, 1.0], 6) * rng.uniform(5.0, 15.0, 6)
