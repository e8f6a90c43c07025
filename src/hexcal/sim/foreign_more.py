"""More effects outside the catalogue, for judging the covariate explorer on what nobody here
wrote an effect for: errors that follow the platform's orientation or position, another leg's
stroke, a cyclic encoder error, products with the axial force, a leg's inclination, a lab's
own sensor column, uneven heating in time, and a tracker knocked mid-session. Simulator hooks only (and one
change to the measured poses), never registered; the sessions are in
:mod:`hexcal.sim.foreign_cases`.

Every hook returns the extra geometric length (N, 6) mm the legs have beyond their readings
(``length = reading + offset + Σ hooks``) and sees the whole session at once (N poses in
recording order), as :func:`hexcal.sim.inject.zero_jump_hook` does.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.effects import EffectData
from hexcal.effects.backlash import motion_state
from hexcal.effects.compliance import leg_forces
from hexcal.io.measurements import Measurements
from hexcal.model.robot import Robot
from hexcal.sim.simulate import LengthEffect, PoseContext

#: The platform's angles a hook may follow: roll, pitch, yaw (deg, extrinsic x-y-z, as the
#: exports write them) and tilt (deg, the platform normal's angle from the base's z).
ANGLES = ("roll", "pitch", "yaw", "tilt")
#: The platform's position coordinates (mm).
AXES = ("x", "y", "z")


def platform_angle(rotation: np.ndarray, name: str) -> np.ndarray:
    """(N,) deg: ``roll``, ``pitch`` or ``yaw`` of the rotations (N, 3, 3) (extrinsic x-y-z
    Euler angles, as :mod:`hexcal.app.export_linuxcnc` writes them), or ``tilt``, the angle of
    the platform's normal from the base's z axis."""
    if name == "tilt":
        return np.rad2deg(np.arccos(np.clip(rotation[:, 2, 2], -1.0, 1.0)))
    if name not in ANGLES:
        raise ValueError(f"no platform angle {name!r}; the angles: {', '.join(ANGLES)}")
    return Rotation.from_matrix(rotation).as_euler("xyz", degrees=True)[:, ANGLES.index(name)]


def _data(truth: Robot, readings: np.ndarray, ctx: PoseContext) -> EffectData:
    return EffectData(
        readings, ctx.position, ctx.rotation, ctx.t, ctx.temperature, truth, truth.a, truth.b
    )


def yaw_x_stroke(
    coef_mm: np.ndarray, middle_mm: float = 60.0, per_deg: float = 5.0
) -> LengthEffect:
    """Leg k is ``coef_mm[k]``·(yaw/``per_deg``)·(reading − ``middle_mm``)/10 longer than it
    reads: an encoder's reader head that the platform's turn twists along its scale, so that
    the scale's error grows with the yaw (an interaction: along the stroke alone, or the yaw
    alone, it averages away)."""
    coef = np.asarray(coef_mm, float)

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        yaw = platform_angle(ctx.rotation, "yaw")
        return coef * (yaw[:, None] / per_deg) * (readings - middle_mm) / 10.0

    hook.__name__ = "hidden_yaw_x_stroke"
    return hook


def windup_x_stroke(
    coef_mm: np.ndarray, start_mm: float = 20.0, per_mm: float = 50.0
) -> LengthEffect:
    """Leg k reads ``coef_mm[k]``·s·(reading − ``start_mm``)/``per_mm`` short, s = ±1 the
    direction of its last move: a screw's friction winding it up by more the longer its free
    length (hysteresis that grows along the stroke: the catalogue's backlash is one play for
    every reading)."""
    coef = np.asarray(coef_mm, float)

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        s = motion_state(readings, 0.02)
        return coef * s * (readings - start_mm) / per_mm

    hook.__name__ = "hidden_windup_x_stroke"
    return hook


def settling_per_step(amp_mm: np.ndarray, tau_s: float) -> Callable[[Measurements], Measurements]:
    """The session with each leg reading ``amp_mm[k]``·e^(−s/``tau_s``) long, s the time since
    its procedure step began (a clamp that seats, a leg that relaxes, anew in every step):
    applied to the measured session, whose steps the poses' own hooks do not see."""
    amp = np.asarray(amp_mm, float)

    def finish(meas: Measurements) -> Measurements:
        since = np.zeros(len(meas))
        began = 0
        for i in range(len(meas)):  # recording order: a step begins where the label changes
            if i and meas.step[i] != meas.step[i - 1]:
                began = i
            since[i] = meas.t[i] - meas.t[began]
        readings = meas.readings + amp * np.exp(-since / tau_s)[:, None]
        return dataclasses.replace(meas, readings=readings)

    return finish


def angle_pull(
    name: str, coef_mm: np.ndarray, power: int = 1, knee_deg: float | None = None
) -> LengthEffect:
    """Leg k is ``coef_mm[k]``·uᵖ longer than it reads (less its session mean), u the angle
    in degrees (:func:`platform_angle`), or with ``knee_deg`` how far the angle is past it
    (0 before): an encoder cable dragged as the platform turns (``yaw``), a cable pulled taut
    once the platform rolls or pitches past a point, a joint reaching its stop as the platform
    tilts (``tilt``). ``coef_mm`` in mm/degᵖ."""
    coef = np.asarray(coef_mm, float)

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        a = platform_angle(ctx.rotation, name)
        u = a if knee_deg is None else np.maximum(a - knee_deg, 0.0)
        v = u**power
        return coef * (v - v.mean())[:, None]

    hook.__name__ = f"hidden_{name}_pull"
    return hook


def turn_friction(name: str, coef_mm: np.ndarray, deadband_deg: float = 0.005) -> LengthEffect:
    """Leg k reads ``coef_mm[k]``·s short, s = ±1 the direction of the platform's last turn in
    ``name`` (roll, pitch or yaw; 0 before its first turn): a cable or a hose whose friction
    the platform's turn drags one way or the other, hysteresis of the platform's motion, not
    of the leg's own (a leg's ``last_move`` need not reverse when the platform's turn does)."""
    coef = np.asarray(coef_mm, float)

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        a = platform_angle(ctx.rotation, name)[:, None]
        return coef * motion_state(a, deadband_deg)

    hook.__name__ = f"hidden_{name}_turn_friction"
    return hook


def leg_inclination(truth: Robot, position: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """(N, 6) deg: each leg's angle from the base's z axis at the poses (position (N, 3) mm,
    rotation (N, 3, 3))."""
    v = position[:, None, :] + np.einsum("nij,kj->nki", rotation, truth.b) - truth.a[None]
    n = v / np.linalg.norm(v, axis=-1, keepdims=True)
    return np.rad2deg(np.arccos(np.clip(n[..., 2], -1.0, 1.0)))


def joint_seating(truth: Robot, coef_mm: np.ndarray) -> LengthEffect:
    """Leg k is ``coef_mm[k]``·(θ_k − θ_k at home)² longer than it reads, θ_k its angle from
    the vertical in degrees: a joint whose seat shifts as the leg leans away from where it
    was assembled (mm/deg²). A sag ∝ sin²θ the joint positions take up
    (:func:`hexcal.sim.foreign.leg_sag`); a bend about the home angle they do not."""
    coef = np.asarray(coef_mm, float)
    home = truth.home
    rot = Rotation.from_quat(home.quaternion, scalar_first=True).as_matrix()[None]
    at_home = leg_inclination(truth, np.asarray(home.position, float)[None], rot)

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        return coef * (leg_inclination(truth, ctx.position, ctx.rotation) - at_home) ** 2

    hook.__name__ = "hidden_joint_seating"
    return hook


def position_pull(axis: int, coef_mm: np.ndarray, centre_mm: float) -> LengthEffect:
    """Leg k is ``coef_mm[k]``·(u − ``centre_mm``)/10 mm longer than it reads, u the platform's
    coordinate along ``axis`` (0 x, 1 y, 2 z), mm: a cable dragged by the platform's position.
    ``coef_mm``: mm per 10 mm of travel."""
    coef = np.asarray(coef_mm, float)

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        return coef * ((ctx.position[:, axis] - centre_mm) / 10.0)[:, None]

    hook.__name__ = f"hidden_{AXES[axis]}_pull"
    return hook


def cross_talk(leg: int, source: int, coef: float, centre_mm: float) -> LengthEffect:
    """Leg ``leg`` (1-based) reads short by ``coef``·(leg ``source``'s reading − ``centre_mm``):
    its encoder picks up another leg's signal (a shared cable, a ground loop), mm per mm."""
    if leg == source:
        raise ValueError(f"cross-talk needs two legs; got leg {leg} twice")

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        out = np.zeros_like(readings)
        out[:, leg - 1] = coef * (readings[:, source - 1] - centre_mm)
        return out

    hook.__name__ = f"hidden_cross_talk_{source}_to_{leg}"
    return hook


def stroke_cycle(
    period_mm: float,
    amp_mm: np.ndarray,
    phase: np.ndarray,
    second: np.ndarray | None = None,
    second_phase: np.ndarray | None = None,
) -> LengthEffect:
    """Leg k reads short by ``amp_mm[k]``·sin(2π·reading/``period_mm`` + ``phase[k]``): a
    cyclic encoder error (an eccentric code wheel on a pinion, a scale's interpolation error)
    whose period is not the lead screw's. A leg with amplitude 0 has none. ``second`` (6,):
    plus ``amp_mm[k]``·``second[k]``·sin(4π·reading/``period_mm`` + ``second_phase[k]``), the
    second harmonic an interpolation error carries (a cycle that is not a pure sine)."""
    amp, ph = np.asarray(amp_mm, float), np.asarray(phase, float)
    two = np.zeros(6) if second is None else np.asarray(second, float)
    ph2 = np.zeros(6) if second_phase is None else np.asarray(second_phase, float)

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        w = 2 * np.pi * readings / period_mm
        return amp * (np.sin(w + ph) + two * np.sin(2 * w + ph2))

    hook.__name__ = f"hidden_cycle_{period_mm:g}mm"
    return hook


def stroke_step(at_mm: np.ndarray, size_mm: np.ndarray) -> LengthEffect:
    """Leg k reads ``size_mm[k]`` short from reading ``at_mm[k]`` on: a joint between two
    lengths of an encoder scale, a tape reader that skips at one place. A leg of size 0 has
    none."""
    at, size = np.asarray(at_mm, float), np.asarray(size_mm, float)

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        return size * (readings >= at)

    hook.__name__ = "hidden_scale_joint"
    return hook


def force_product(truth: Robot, coef: np.ndarray, kind: str) -> LengthEffect:
    """Leg k shortens by ``coef[k]``·F_k·X_k under its axial force F_k (N, compression
    positive, holding the platform's weight as :func:`~hexcal.effects.compliance.leg_forces`
    computes it): ``kind`` ``"stroke"``, X the reading (mm; a screw whose loaded length grows
    with the extension; ``coef`` in mm/(N·mm)), or ``"length2"``, X the leg's length squared
    (mm²; a slender leg bowing under its axial load, whose shortening grows as F·L²; ``coef``
    in mm/(N·mm²))."""
    c = np.asarray(coef, float)
    mass = truth.platform_mass_kg or 1.0
    if kind not in ("stroke", "length2"):
        raise ValueError(f"force_product kind {kind!r}: use 'stroke' or 'length2'")

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        data = _data(truth, readings, ctx)
        x = readings if kind == "stroke" else data.lengths**2
        return -c * leg_forces(data, mass) * x

    hook.__name__ = f"hidden_force_x_{kind}"
    return hook


def load_friction(truth: Robot, coef_mm: np.ndarray, deadband_n: float = 0.05) -> LengthEffect:
    """Leg k reads ``coef_mm[k]``·s short, s = ±1 whether its axial force (N, as
    :func:`~hexcal.effects.compliance.leg_forces` computes it) last rose or fell (0 before it
    first changes): a joint's friction or a load-dependent part that holds the last load —
    hysteresis of the load's history, not of the leg's motion nor of the load's sign."""
    c = np.asarray(coef_mm, float)
    mass = truth.platform_mass_kg or 1.0

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        return c * motion_state(leg_forces(_data(truth, readings, ctx), mass), deadband_n)

    hook.__name__ = "hidden_load_friction"
    return hook


def series_pull(values: np.ndarray, coef_mm: np.ndarray) -> LengthEffect:
    """Leg k is ``coef_mm[k]``·(v − mean v) longer than it reads, v (N,) a series recorded
    with the session (one value per pose, in recording order): what a lab's own sensor column
    measures (humidity swelling a printed leg, a motor's current heating its encoder)."""
    v = np.asarray(values, float)
    coef = np.asarray(coef_mm, float)

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        if len(readings) != len(v):
            raise ValueError(f"the series has {len(v)} values for {len(readings)} poses")
        return coef * (v - v.mean())[:, None]

    hook.__name__ = "hidden_series_pull"
    return hook


def heating(size_mm: np.ndarray, tau_s: float) -> LengthEffect:
    """Leg k grows ``size_mm[k]``·(1 − e^(−t/τ)) over the session (t from its first pose, s):
    uneven warm-up of the legs (each motor heating its own), smooth in time — no step."""
    size = np.asarray(size_mm, float)

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        t = np.asarray(ctx.t, float)
        return size * (1.0 - np.exp(-(t - t.min()) / tau_s))[:, None]

    hook.__name__ = "hidden_heating"
    return hook


def knock_tracker(
    meas: Measurements, row: int, rotvec_deg: np.ndarray, shift_mm: np.ndarray
) -> Measurements:
    """``meas`` as the tracker reports it when knocked just before pose ``row`` (0-based,
    recording order): from that pose on, every measured pose is moved rigidly — rotated by
    the rotation vector ``rotvec_deg`` (3,) deg about the measurement frame's origin, then
    shifted by ``shift_mm`` (3,) mm. The readings are untouched. Positions and quaternions
    are rounded as the session's are (5 and 9 decimals)."""
    if not 0 < row < len(meas):
        raise ValueError(f"the knock's row {row} is outside 1..{len(meas) - 1}")
    knock = Rotation.from_rotvec(np.deg2rad(np.asarray(rotvec_deg, float)))
    position = meas.position.copy()
    position[row:] = knock.apply(position[row:]) + np.asarray(shift_mm, float)
    rot = Rotation.from_quat(meas.quaternion, scalar_first=True)
    q = meas.quaternion.copy()
    q[row:] = (knock * rot[row:]).as_quat(scalar_first=True)
    return dataclasses.replace(meas, position=np.round(position, 5), quaternion=np.round(q, 9))
