"""Effects outside the catalogue, for testing that the diagnosis says ``unexplained`` instead of
forcing a catalogue effect onto them. They are simulator hooks only, never registered."""

from __future__ import annotations

import numpy as np

from hexcal.effects import EffectData
from hexcal.effects.compliance import leg_forces
from hexcal.model.robot import Robot
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


def _inclination_sin2(truth: Robot, ctx: PoseContext) -> np.ndarray:
    """(N, 6) sin² of each leg's angle from the vertical (z up) at the true poses."""
    v = ctx.position[:, None, :] + np.einsum("nij,kj->nki", ctx.rotation, truth.b) - truth.a[None]
    n = v / np.linalg.norm(v, axis=-1, keepdims=True)
    return 1.0 - n[..., 2] ** 2


def leg_sag(truth: Robot, size_mm: np.ndarray) -> LengthEffect:
    """Each leg's tube bends under its own weight: the distance between its joints falls short
    of what the encoder reads by ``size_mm[k]``·sin²θ_k, θ_k the leg's angle from the vertical
    (the weight's share across the leg, squared: the chord of a bent beam). Follows the
    inclination; compliance (the axial force from the platform's weight) is a different
    pattern."""
    size = np.asarray(size_mm, float)

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        return -size * _inclination_sin2(truth, ctx)

    return hook


def stroke_quadratic(q_per_mm: np.ndarray, centre_mm: float) -> LengthEffect:
    """Each encoder's scale bends along its stroke: leg k reads short by
    ``q_per_mm[k]``·(reading − ``centre_mm``)² (mm per mm²). Its straight part is a gain; the
    bend is not in the catalogue."""
    q = np.asarray(q_per_mm, float)

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        return q * (readings - centre_mm) ** 2

    return hook


def stroke_dent(leg: int, centre_mm: float, width_mm: float, depth_mm: float) -> LengthEffect:
    """A dent at one place of one leg's stroke (a worn stretch of a screw, a dirty scale): leg
    ``leg`` (1-based) reads ``depth_mm`` short at reading ``centre_mm``, fading as a Gaussian of
    standard deviation ``width_mm`` either side."""

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        out = np.zeros_like(readings)
        u = (readings[:, leg - 1] - centre_mm) / width_mm
        out[:, leg - 1] = depth_mm * np.exp(-0.5 * u**2)
        return out

    return hook


def joint_play(truth: Robot, play_mm: np.ndarray) -> LengthEffect:
    """Each leg's joints have ``play_mm[k]`` of clearance, taken up one way while the leg is in
    compression and the other in tension: the distance between the joint centres is
    ``play/2`` shorter under compression than the reading says, and ``play/2`` longer under
    tension. The axial forces hold the platform's weight (``truth.platform_mass_kg``, 1 kg
    without it), so the play shows where a leg's load reverses — unlike backlash, which
    follows the direction of motion."""
    play = np.asarray(play_mm, float)
    mass = truth.platform_mass_kg or 1.0

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        data = EffectData(
            readings, ctx.position, ctx.rotation, ctx.t, ctx.temperature, truth, truth.a, truth.b
        )
        return -0.5 * play * np.sign(leg_forces(data, mass))

    return hook
