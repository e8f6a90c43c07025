"""A held-out set of effects outside the catalogue, written apart from the explorer's own
benchmark set (:mod:`hexcal.sim.foreign_cases`) to check that the explorer generalises: a cable
wrap periodic in yaw, a V in pitch, a product of z and the stroke, a leg's azimuth, a
temperature² error under a room that warms and cools, a lab's column acting on two legs with a
lag, a smooth drift on two legs, a 23 mm cycle on two legs, a dead band along the stroke and a
pitch error that saturates. Simulator hooks only, never registered.

:data:`HELDOUT` names each case and the covariate names (the explorer's own,
docs/diagnosis.md) accepted for it; :func:`heldout` builds its session as
:func:`hexcal.sim.verdict_cases.foreign` builds the team's (Left Hand, 20 kg platform, 184 poses,
the same noise), from a seed base of its own.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from hexcal.io.measurements import Measurements
from hexcal.model.robot import Robot
from hexcal.sim.foreign_more import platform_angle, stroke_cycle
from hexcal.sim.session_sim import simulate_session
from hexcal.sim.simulate import LengthEffect, PoseContext
from hexcal.sim.verdict_cases import INSTRUMENTS, HiddenCase, _start

#: Each case and the covariate names accepted for its one hidden effect.
HELDOUT: dict[str, tuple[str, ...]] = {
    "yaw wrap": ("yaw",),
    "pitch V": ("pitch",),
    "z x stroke": ("z", "stroke"),
    "azimuth": ("azimuth",),
    "temperature squared": ("temperature",),
    "lagged column": ("coolant_temp_c",),
    "two-leg drift": ("time", "pose_index"),
    "cycle 23 mm": ("stroke",),
    "dead band": ("stroke",),
    "pitch tanh": ("pitch",),
}
#: The middle of the Left Hand's readings (mm) and of the room's temperature (°C).
STROKE_MIDDLE_MM, ROOM_C = 60.0, 20.0


def _signs(rng: np.random.Generator, n: int = 6) -> np.ndarray:
    return rng.choice([-1.0, 1.0], n)


def _legs(rng: np.random.Generator, n: int) -> np.ndarray:
    """(6,) 1 on ``n`` legs drawn, 0 on the others."""
    on = np.zeros(6)
    on[rng.choice(6, n, replace=False)] = 1.0
    return on


def _share(t: np.ndarray) -> np.ndarray:
    """(N,) the place in the session, 0 at its first pose and 1 at its last (from times, s)."""
    t = np.asarray(t, float)
    return (t - t[0]) / (t[-1] - t[0])


def angle_shape(
    name: str, coef_mm: np.ndarray, shape: Callable[[np.ndarray], np.ndarray]
) -> LengthEffect:
    """Leg k is ``coef_mm[k]``·shape(u) longer than it reads (less its session mean), u the
    platform angle ``name`` in degrees (:func:`~hexcal.sim.foreign_more.platform_angle`)."""
    coef = np.asarray(coef_mm, float)

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        v = shape(platform_angle(ctx.rotation, name))
        return coef * (v - v.mean())[:, None]

    hook.__name__ = f"hidden_{name}_shape"
    return hook


def z_stroke(coef_mm: np.ndarray, z0_mm: float) -> LengthEffect:
    """Leg k is ``coef_mm[k]``·(z − z0)/10·(reading − 60)/10 longer than it reads: a scale
    whose reader rides on a carriage that the platform's height bends (mm per 10 mm × 10 mm)."""
    coef = np.asarray(coef_mm, float)

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        dz = (ctx.position[:, 2] - z0_mm) / 10.0
        return coef * dz[:, None] * (readings - STROKE_MIDDLE_MM) / 10.0

    hook.__name__ = "hidden_z_x_stroke"
    return hook


def leg_azimuth(truth: Robot, position: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """(N, 6) deg: each leg's direction about the base's z axis at the poses."""
    v = position[:, None, :] + np.einsum("nij,kj->nki", rotation, truth.b) - truth.a[None]
    return np.rad2deg(np.arctan2(v[..., 1], v[..., 0]))


def azimuth_wrap(truth: Robot, coef_mm: np.ndarray) -> LengthEffect:
    """Leg k is ``coef_mm[k]``·Δφ_k² longer than it reads, Δφ_k its azimuth's turn from its
    session mean (deg, wrapped): a cable wound about the base joint as the leg swings
    (mm/deg²)."""
    coef = np.asarray(coef_mm, float)

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        phi = leg_azimuth(truth, ctx.position, ctx.rotation)
        d = (phi - phi.mean(axis=0) + 180.0) % 360.0 - 180.0
        return coef * (d**2 - (d**2).mean(axis=0))

    hook.__name__ = "hidden_azimuth_wrap"
    return hook


def room(swing_k: float, cycles: float, phase: float) -> Callable[[np.ndarray], np.ndarray]:
    """The room's temperature (°C) at times t (N,) s: ``ROOM_C`` + ``swing_k``·sin over
    ``cycles`` periods of the session (an air conditioner cycling), so that it is no monotone
    function of time."""

    def temperature(t: np.ndarray) -> np.ndarray:
        return ROOM_C + swing_k * np.sin(2 * np.pi * cycles * _share(t) + phase)

    return temperature


def write_temperature(
    temperature: Callable[[np.ndarray], np.ndarray],
) -> Callable[[Measurements], Measurements]:
    """The finish writing the room's temperature into the session (0.01 K)."""

    def finish(meas: Measurements) -> Measurements:
        return dataclasses.replace(meas, temperature=np.round(temperature(meas.t), 2))

    return finish


def temperature_squared(
    temperature: Callable[[np.ndarray], np.ndarray], coef_mm: np.ndarray
) -> LengthEffect:
    """Leg k is ``coef_mm[k]``·(T − 20 °C)² longer than it reads (less its mean): an encoder
    whose scale bows both ways from its assembly temperature (mm/K²)."""
    coef = np.asarray(coef_mm, float)

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        v = (temperature(ctx.t) - ROOM_C) ** 2
        return coef * (v - v.mean())[:, None]

    hook.__name__ = "hidden_temperature_squared"
    return hook


def lagged(values: np.ndarray, t: np.ndarray, tau_s: float) -> np.ndarray:
    """(N,) ``values`` through a first-order lag of ``tau_s`` s over the times ``t`` (N,) s
    (the first value held before the session): what a part follows with its own thermal mass."""
    out = np.empty(len(values))
    out[0] = values[0]
    for i in range(1, len(values)):
        w = 1.0 - np.exp(-(t[i] - t[i - 1]) / tau_s)
        out[i] = out[i - 1] + w * (values[i] - out[i - 1])
    return out


def coolant(rng: np.random.Generator) -> Callable[[np.ndarray], np.ndarray]:
    """A lab's coolant thermometer (°C) at times t (N,) s: 18 °C, 0.5 K standard deviation, a
    smooth random series (three sinusoids of 10–30 % of the session)."""
    period, phase = rng.uniform(0.10, 0.30, 3), rng.uniform(0, 2 * np.pi, 3)
    weight = rng.uniform(0.5, 1.0, 3)

    def series(t: np.ndarray) -> np.ndarray:
        s = np.sin(2 * np.pi * _share(t)[:, None] / period + phase) @ weight
        return np.round(18.0 + 0.5 * (s - s.mean()) / s.std(), 2)

    return series


def column_lagged(
    series: Callable[[np.ndarray], np.ndarray], coef_mm: np.ndarray, tau_share: float
) -> LengthEffect:
    """Leg k is ``coef_mm[k]``·(v − mean v) longer than it reads, v the column ``series``
    through a lag of ``tau_share`` of the session (mm per unit of the column)."""
    coef = np.asarray(coef_mm, float)

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        t = np.asarray(ctx.t, float)
        v = lagged(series(t), t, tau_share * (t[-1] - t[0]))
        return coef * (v - v.mean())[:, None]

    hook.__name__ = "hidden_lagged_column"
    return hook


def write_column(
    name: str, series: Callable[[np.ndarray], np.ndarray]
) -> Callable[[Measurements], Measurements]:
    """The finish writing the column ``name`` into the session (two decimals)."""

    def finish(meas: Measurements) -> Measurements:
        text = np.array([f"{v:.2f}" for v in series(meas.t)], dtype=object)
        extra = {**meas.extra, name: text}
        return dataclasses.replace(meas, extra=extra, columns=(*meas.columns, name))

    return finish


def s_drift(size_mm: np.ndarray, centre: float, width: float) -> LengthEffect:
    """Leg k grows ``size_mm[k]``·(1 + tanh((u − centre)/width))/2, u the place in the session
    (0..1): a leg settling in its clamp over a few minutes, smooth in time."""
    size = np.asarray(size_mm, float)

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        return size * (0.5 * (1 + np.tanh((_share(ctx.t) - centre) / width)))[:, None]

    hook.__name__ = "hidden_s_drift"
    return hook


def dead_band(knee_mm: np.ndarray, coef: np.ndarray) -> LengthEffect:
    """Leg k reads short by ``coef[k]``·(reading − ``knee_mm[k]``) past the knee, nothing
    before: a scale stretched over its last stretch (mm per mm)."""
    knee, c = np.asarray(knee_mm, float), np.asarray(coef, float)

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        return c * np.maximum(readings - knee, 0.0)

    hook.__name__ = "hidden_dead_band"
    return hook


Finish = Callable[[Measurements], Measurements] | None


def draw_heldout(case: str, rng: np.random.Generator, truth: Robot) -> tuple[LengthEffect, Finish]:
    """The hidden effect of ``case`` (:data:`HELDOUT`) for a session of the robot ``truth``,
    and the finish writing what the instruments record besides (or None), drawn from ``rng``."""
    if case == "yaw wrap":  # 30–50 µm, period 8–14° over the ±15° of yaw
        amp, period = rng.uniform(0.03, 0.05, 6), float(rng.uniform(8.0, 14.0))
        ph = rng.uniform(0, 2 * np.pi)
        return angle_shape("yaw", amp, lambda u: np.sin(2 * np.pi * u / period + ph)), None
    if case == "pitch V":  # 5–8 µm/° of |pitch|: 75–120 µm at 15°
        return angle_shape("pitch", _signs(rng) * rng.uniform(0.005, 0.008, 6), np.abs), None
    if case == "pitch tanh":  # ±45–70 µm, saturating within 2–4°
        w = float(rng.uniform(2.0, 4.0))
        coef = _signs(rng) * rng.uniform(0.045, 0.07, 6)
        return angle_shape("pitch", coef, lambda u: np.tanh(u / w)), None
    if case == "z x stroke":  # 6–12 µm per (10 mm × 10 mm)
        coef = _signs(rng) * rng.uniform(0.006, 0.012, 6)
        return z_stroke(coef, float(truth.home.position[2])), None
    if case == "azimuth":  # 0.1–0.2 µm/deg²
        return azimuth_wrap(truth, _signs(rng) * rng.uniform(0.0001, 0.0002, 6)), None
    if case == "temperature squared":  # ±2.5–3.5 K swing, 6–10 µm/K²
        t_of = room(float(rng.uniform(2.5, 3.5)), float(rng.uniform(1.2, 2.0)), rng.uniform(0, 6))
        coef = _signs(rng) * rng.uniform(0.006, 0.010, 6)
        return temperature_squared(t_of, coef), write_temperature(t_of)
    if case == "lagged column":  # two legs, 120–160 µm per K, lag 3–8 % of the session
        series = coolant(rng)
        coef = _legs(rng, 2) * _signs(rng) * rng.uniform(0.12, 0.16, 6)
        hook = column_lagged(series, coef, float(rng.uniform(0.03, 0.08)))
        return hook, write_column("coolant_temp_c", series)
    if case == "two-leg drift":  # two legs 60–100 µm, centred in the middle half
        size = _legs(rng, 2) * _signs(rng) * rng.uniform(0.06, 0.10, 6)
        hook = s_drift(size, float(rng.uniform(0.3, 0.7)), float(rng.uniform(0.1, 0.2)))
        t_of = room(float(rng.uniform(1.0, 2.0)), 1.5, float(rng.uniform(0, 6)))
        return hook, write_temperature(t_of)
    if case == "cycle 23 mm":  # two legs, 50–80 µm
        amp = _legs(rng, 2) * rng.uniform(0.05, 0.08, 6)
        return stroke_cycle(23.0, amp, rng.uniform(0, 2 * np.pi, 6)), None
    if case == "dead band":  # 3–5 legs, 5–8 µm/mm past 70–80 mm
        coef = _legs(rng, int(rng.integers(3, 6))) * _signs(rng) * rng.uniform(0.005, 0.008, 6)
        return dead_band(rng.uniform(70.0, 80.0, 6), coef), None
    raise ValueError(f"no held-out case {case!r}; the cases: {', '.join(HELDOUT)}")


#: The seeds' base: apart from the team's cases (50 000–100 000).
SEED_BASE = 340_000


def heldout(case: str, seed: int) -> HiddenCase:
    """The session of ``case`` (:data:`HELDOUT`): the hidden effect drawn from ``seed``, its
    expected verdict ``unexplained`` and the covariates accepted for it."""
    if case not in HELDOUT:
        raise ValueError(f"no held-out case {case!r}; the cases: {', '.join(HELDOUT)}")
    design, rng, plan, truth = _start(seed, SEED_BASE)
    hook, finish = draw_heldout(case, rng, truth)
    meas, _ = simulate_session(design, seed, plan, effects=[hook], truth=truth)
    if finish is not None:
        meas = finish(meas)
    accepted = HELDOUT[case]
    return HiddenCase(
        meas,
        design,
        INSTRUMENTS,
        case,
        "unexplained",
        covariate=accepted[0],
        covariates=(accepted,),
    )


def clean_twin(seed: int) -> HiddenCase:
    """The session every case of ``seed`` is built on, with nothing hidden: the same true
    robot, poses and noise (what Model 42 leaves on it is the level a written file can reach
    on that seed, which sits above the floor by chance: 0.98–1.14× on seeds 0–3)."""
    design, _, plan, truth = _start(seed, SEED_BASE)
    meas, _ = simulate_session(design, seed, plan, truth=truth)
    return HiddenCase(meas, design, INSTRUMENTS, "clean twin", "none")
