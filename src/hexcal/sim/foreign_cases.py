"""The sessions of :mod:`hexcal.sim.foreign_more`'s effects, each drawn from its seed (which
legs, sizes, phases, periods, axes, the knock's row) and sized so that Model 42 leaves a
held-out error of at least twice the noise floor on every seed (tests/test_foreign_more.py
holds that contract on a few seeds; the sizes stay at hardware magnitudes, tens of µm).

:data:`MORE` names the cases and the covariates the explorer may name for them; a case whose
covariate is drawn (another leg's stroke, an axis, a user column's name) lists the class, and
:func:`draw` gives the session's own. The session itself (Left Hand, 20 kg platform, 184
poses, the noise) is :func:`hexcal.sim.verdict_cases.foreign`'s.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hexcal.io.measurements import Measurements
from hexcal.model.robot import Robot
from hexcal.sim.foreign_more import (
    AXES,
    angle_pull,
    cross_talk,
    force_product,
    heating,
    joint_seating,
    knock_tracker,
    load_friction,
    position_pull,
    series_pull,
    settling_per_step,
    stroke_cycle,
    stroke_step,
    turn_friction,
    windup_x_stroke,
    yaw_x_stroke,
)
from hexcal.sim.simulate import LengthEffect, PoseContext

#: Each case and the covariates it is judged on: one tuple per hidden effect, of the names
#: accepted for it (``stroke_legJ``, ``x|y|z``, ``roll|pitch`` and the user column are drawn
#: per session: :attr:`Drawn.covariates` holds the session's own).
MORE: dict[str, tuple[tuple[str, ...], ...]] = {
    "yaw cable": (("yaw",),),
    "yaw x stroke": (("stroke*yaw",),),
    "windup x stroke": (("stroke*last_move",),),
    "settling per step": (("step_time",),),
    "hose taut": (("roll", "pitch"),),
    "turn friction": (tuple(f"platform_move_{a}" for a in ("roll", "pitch", "yaw")),),
    "tilt error": (("tilt",),),
    "roll or pitch cable": (("roll", "pitch"),),
    "cross-talk": (tuple(f"stroke_leg{j}" for j in range(1, 7)),),
    "cycle 7.3 mm": (("stroke",),),
    "scale joint": (("stroke",),),
    "cycle 11-17 mm": (("stroke",),),
    "cycle with harmonic": (("stroke",),),
    "bending": (("force_x_length2",),),
    "force x stroke": (("force_x_stroke",),),
    "load friction": (("force_change",),),
    "user column": (("humidity_pct", "motor_current_a", "air_pressure_hpa"),),
    "position pull": (AXES,),
    "joint seating": (("inclination",),),
    "uneven heating": (("time",),),
    "tracker knocked": (),
    "yaw cable + cycle 7.3 mm": (("yaw",), ("stroke",)),
    "bending + user column": (
        ("force_x_length2",),
        ("humidity_pct", "motor_current_a", "air_pressure_hpa"),
    ),
}
#: The verdict each case should reach where it is not ``unexplained``.
EXPECTED = {"tracker knocked": "frame_step"}
#: The cyclic error's period, mm: the Left Hand's lead screw has a 5 mm pitch, and 7.3 mm is
#: neither it nor a harmonic (5/n) or multiple of it.
CYCLE_MM = 7.3
#: A lab's own sensor columns: (name, its mean, its standard deviation, decimals written).
USER_COLUMNS = (
    ("humidity_pct", 45.0, 4.0, 2),
    ("motor_current_a", 1.2, 0.15, 3),
    ("air_pressure_hpa", 1013.0, 3.0, 2),
)
#: The tracker's knock: the rotation (deg) and the shift (mm) drawn, each in a random direction.
KNOCK_DEG = (0.02, 0.025)
KNOCK_MM = (0.08, 0.12)
#: and the platform's home moves at least this far (mm)
KNOCK_HOME_MM = 0.1
#: Bending and force × stroke are sized at a typical pose of the Left Hand with a 20 kg
#: platform: axial force 33 N, leg length 200 mm, reading 60 mm.
FORCE_N, LENGTH_MM, READING_MM = 33.0, 200.0, 60.0


@dataclass(frozen=True)
class Drawn:
    """What a case hides in its session, drawn from the seed."""

    hooks: list[LengthEffect]
    #: one tuple per hidden effect: the covariate names accepted for it in this session
    covariates: tuple[tuple[str, ...], ...]
    expected: str = "unexplained"
    #: the measured session as the instruments report it (a knocked tracker, a user column,
    #: the room's temperature), from the simulated one
    finish: Callable[[Measurements], Measurements] | None = None
    #: ``tracker knocked``: the row (0-based) of the first pose after the knock
    frame_row: int | None = None


def _signs(rng: np.random.Generator, n: int = 6) -> np.ndarray:
    return rng.choice([-1.0, 1.0], n)


def _subset(rng: np.random.Generator, low: int, high: int) -> np.ndarray:
    """(6,) 1 on ``low``–``high`` legs drawn, 0 on the others."""
    on = np.zeros(6)
    on[rng.choice(6, int(rng.integers(low, high + 1)), replace=False)] = 1.0
    return on


@dataclass(frozen=True)
class UserSeries:
    """A lab's own sensor, read at every pose: a smooth random series in time (sinusoids of
    periods 6–25 % of the session) with its straight-line parts in time and temperature
    projected out, so that neither column follows it; written to ``decimals``."""

    name: str
    mean: float
    sd: float
    decimals: int
    period: np.ndarray  #: (W,) share of the session
    phase: np.ndarray  #: (W,) rad
    weight: np.ndarray  #: (W,)

    def __call__(self, t: np.ndarray, temperature: np.ndarray) -> np.ndarray:
        """(N,) the column's values at the poses' times (s) and temperatures (°C)."""
        t = np.asarray(t, float)
        u = (t - t[0]) / (t[-1] - t[0])
        s = np.sin(2 * np.pi * u[:, None] / self.period + self.phase) @ self.weight
        x = np.column_stack([np.ones_like(u), u, np.asarray(temperature, float)])
        s = s - x @ np.linalg.lstsq(x, s, rcond=None)[0]
        return np.round(self.mean + self.sd * s / s.std(), self.decimals)


def user_series(rng: np.random.Generator) -> UserSeries:
    name, mean, sd, decimals = USER_COLUMNS[int(rng.integers(len(USER_COLUMNS)))]
    return UserSeries(
        name,
        mean,
        sd,
        decimals,
        rng.uniform(0.06, 0.25, 4),
        rng.uniform(0, 2 * np.pi, 4),
        rng.uniform(0.5, 1.0, 4),
    )


def _user_column(rng: np.random.Generator) -> tuple[LengthEffect, str, Callable]:
    """The hook (each leg 15–30 µm per standard deviation of the column, signs drawn), the
    column's name, and the finish writing the column into the session."""
    series = user_series(rng)
    coef = _signs(rng) * rng.uniform(0.015, 0.030, 6) / series.sd

    def hook(readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        return series_pull(series(ctx.t, ctx.temperature), coef)(readings, ctx)

    def finish(meas: Measurements) -> Measurements:
        assert meas.temperature is not None  # every session here records it
        text = [f"{v:.{series.decimals}f}" for v in series(meas.t, meas.temperature)]
        extra = {**meas.extra, series.name: np.array(text, dtype=object)}
        return dataclasses.replace(meas, extra=extra, columns=(*meas.columns, series.name))

    return hook, series.name, finish


def _room(rng: np.random.Generator) -> Callable[[Measurements], Measurements]:
    """The room's temperature for ``uneven heating``: up 2–4 K to a peak at 35–65 % of the
    session, then back down by half of that, so the temperature is no monotone function of
    time and a curve in time is not one in temperature (0.05 K jitter, 0.01 K written)."""
    rise, peak = rng.uniform(2.0, 4.0), rng.uniform(0.35, 0.65)
    jitter_rng = np.random.default_rng(rng.integers(2**32))

    def finish(meas: Measurements) -> Measurements:
        u = (meas.t - meas.t[0]) / (meas.t[-1] - meas.t[0])
        shape = np.where(u <= peak, u / peak, 1.0 - 0.5 * (u - peak) / (1.0 - peak))
        temp = 20.0 + rise * shape + jitter_rng.normal(0.0, 0.05, len(u))
        return dataclasses.replace(meas, temperature=np.round(temp, 2))

    return finish


def _draw_shapes(case: str, rng: np.random.Generator) -> Drawn | None:
    """The cases of the classes added with the explorer's products, its step time and its bend
    (two covariates acting together, a sign among them; a settling in every step; a knee in an
    angle), or None for another case."""
    if case == "yaw x stroke":
        # 12–18 µm per 5° × 10 mm on every leg: 40–90 µm at the stroke's ends and ±15° of yaw
        coef = _signs(rng) * rng.uniform(0.012, 0.018, 6)
        return Drawn([yaw_x_stroke(coef)], (("stroke*yaw",),))
    if case == "windup x stroke":
        # 20–35 µm per 50 mm of free length, either way as the leg last moved, every leg
        coef = rng.uniform(0.02, 0.035, 6)
        return Drawn([windup_x_stroke(coef)], (("stroke*last_move",),))
    if case == "settling per step":
        # 3 legs, 60–100 µm at each step's start, settling with τ 20–60 s (a step lasts 2–9 min)
        amp = _subset(rng, 3, 3) * _signs(rng) * rng.uniform(0.06, 0.10, 6)
        return Drawn(
            [], (("step_time",),), finish=settling_per_step(amp, float(rng.uniform(20, 60)))
        )
    if case == "hose taut":
        # A hose slack until the platform rolls (or pitches) past 1–4°, then pulling every leg
        # by 9–14 µm per degree beyond: a bend, flat on one side of its knee
        name = str(rng.choice(["roll", "pitch"]))
        coef = _signs(rng) * rng.uniform(0.009, 0.014, 6)
        return Drawn([angle_pull(name, coef, knee_deg=float(rng.uniform(1.0, 4.0)))], ((name,),))
    return None


def _draw_directions(case: str, rng: np.random.Generator, truth: Robot) -> Drawn | None:
    """The cases of the classes added with the covariates of a change's direction (the
    platform's turn, the load's rise or fall) and the cycle's harmonics, or None for another
    case."""
    if case == "turn friction":
        # a cable dragged one way or the other as the platform last turned in roll, pitch or
        # yaw: every leg 20–40 µm, either sign (the platform's hysteresis, not a leg's)
        name = str(rng.choice(["roll", "pitch", "yaw"]))
        coef = _signs(rng) * rng.uniform(0.02, 0.04, 6)
        return Drawn([turn_friction(name, coef)], ((f"platform_move_{name}",),))
    if case == "load friction":
        # every leg 20–40 µm either way as its load last rose or fell
        return Drawn(
            [load_friction(truth, _signs(rng) * rng.uniform(0.02, 0.04, 6))], (("force_change",),)
        )
    if case == "cycle with harmonic":
        # an interpolation error that is not a pure sine: period 6–9 mm, 25–40 µm, and its
        # second harmonic at 40–80 % of it, every leg its own phases
        period = float(rng.uniform(6.0, 9.0))
        amp, ph = rng.uniform(0.025, 0.04, 6), rng.uniform(0, 2 * np.pi, 6)
        second, ph2 = rng.uniform(0.4, 0.8, 6), rng.uniform(0, 2 * np.pi, 6)
        return Drawn([stroke_cycle(period, amp, ph, second, ph2)], (("stroke",),))
    return None


def draw(case: str, rng: np.random.Generator, truth: Robot, n_poses: int) -> Drawn:
    """The hidden effect(s) of ``case`` (:data:`MORE`) for a session of ``n_poses`` poses of
    the robot ``truth``, drawn from ``rng``."""
    if case not in MORE:
        raise ValueError(f"no foreign case {case!r}; the cases: {', '.join(MORE)}")
    if " + " in case:
        first, second = case.split(" + ")
        a, b = draw(first, rng, truth, n_poses), draw(second, rng, truth, n_poses)
        finishes = [f for f in (a.finish, b.finish) if f is not None]

        def finish(meas: Measurements) -> Measurements:
            for f in finishes:
                meas = f(meas)
            return meas

        return Drawn([*a.hooks, *b.hooks], a.covariates + b.covariates, finish=finish)
    shaped = _draw_shapes(case, rng)
    if shaped is None:
        shaped = _draw_directions(case, rng, truth)
    if shaped is not None:
        return shaped
    if case == "yaw cable":
        # 1.5–4 µm/deg on every leg: 20–60 µm at the ±15° the session turns the platform
        return Drawn([angle_pull("yaw", _signs(rng) * rng.uniform(0.0015, 0.004, 6))], (("yaw",),))
    if case == "roll or pitch cable":
        # A hose pulled as the platform rolls (or pitches) either way: 35–55 µm at 10°, as the
        # angle² (a straight line in roll or pitch the geometry takes up; a knee mostly too)
        name = str(rng.choice(["roll", "pitch"]))
        coef = _signs(rng) * rng.uniform(0.035, 0.055, 6) / 10.0**2
        return Drawn([angle_pull(name, coef, power=2)], ((name,),))
    if case == "tilt error":
        # joints seating as the platform tilts, on 4–6 legs: 30–50 µm at 10°, as the tilt²
        # (the geometry takes up about half of it: a straight line in tilt is taken up alike)
        coef = _signs(rng) * _subset(rng, 4, 6) * rng.uniform(0.03, 0.05, 6) / 10.0**2
        return Drawn([angle_pull("tilt", coef, power=2)], (("tilt",),))
    if case == "cross-talk":
        source, *legs = (int(k) + 1 for k in rng.choice(6, 3, replace=False))
        # two legs pick up 2.4–3.4 µm per mm of a third's reading: 70–100 µm at ±30 mm
        coef = _signs(rng, 2) * rng.uniform(0.0024, 0.0034, 2)
        hooks = [cross_talk(k, source, float(c), 55.0) for k, c in zip(legs, coef, strict=True)]
        return Drawn(hooks, ((f"stroke_leg{source}",),))
    if case == "scale joint":
        # 3–4 legs read 60–90 µm short past one place of their stroke (drawn in its middle)
        size = _subset(rng, 3, 4) * _signs(rng) * rng.uniform(0.06, 0.09, 6)
        return Drawn([stroke_step(rng.uniform(45.0, 75.0, 6), size)], (("stroke",),))
    if case == "cycle 7.3 mm":
        amp = rng.uniform(0.024, 0.042, 6)
        return Drawn([stroke_cycle(CYCLE_MM, amp, rng.uniform(0, 2 * np.pi, 6))], (("stroke",),))
    if case == "cycle 11-17 mm":
        period = float(rng.uniform(11.0, 17.0))
        while abs(period - 15.0) < 0.5:  # 15 mm: three lead-screw pitches
            period = float(rng.uniform(11.0, 17.0))
        amp = _subset(rng, 3, 5) * rng.uniform(0.04, 0.06, 6)
        return Drawn([stroke_cycle(period, amp, rng.uniform(0, 2 * np.pi, 6))], (("stroke",),))
    if case == "bending":
        # each leg 45–100 µm shorter at the typical force and length
        coef = rng.uniform(0.045, 0.1, 6) / (FORCE_N * LENGTH_MM**2)
        return Drawn([force_product(truth, coef, "length2")], (("force_x_length2",),))
    if case == "force x stroke":
        # 4–6 legs 50–110 µm shorter at the typical force and reading
        coef = _subset(rng, 4, 6) * rng.uniform(0.05, 0.11, 6) / (FORCE_N * READING_MM)
        return Drawn([force_product(truth, coef, "stroke")], (("force_x_stroke",),))
    if case == "user column":
        hook, name, finish = _user_column(rng)
        return Drawn([hook], ((name,),), finish=finish)
    if case == "position pull":
        axis = int(rng.integers(3))
        centre = float(truth.home.position[axis])
        # 15–35 µm per 10 mm of travel: 45–105 µm at the ±30 mm the session reaches
        coef = _signs(rng) * rng.uniform(0.015, 0.035, 6)
        return Drawn([position_pull(axis, coef, centre)], ((AXES[axis],),))
    if case == "joint seating":
        # 0.9–1.4 µm/deg² per leg, signs drawn: 22–35 µm 5° from the leg's angle at home
        coef = _signs(rng) * rng.uniform(0.0009, 0.0014, 6)
        return Drawn([joint_seating(truth, coef)], (("inclination",),))
    if case == "uneven heating":
        tau = float(rng.uniform(480.0, 1200.0))  # s: legs warm up over 8–20 min
        size = rng.uniform(0.06, 0.12, 6)
        return Drawn([heating(size, tau)], (("time",),), finish=_room(rng))
    # tracker knocked
    row = int(rng.integers(n_poses // 4, 3 * n_poses // 4))
    home = np.asarray(truth.home.position, float)
    while True:  # a knock whose turn and shift cancel at the platform hides in the geometry
        # the stand tips more than it turns: the turn's axis mostly horizontal
        turn, shift = rng.normal(size=3) * [1.0, 1.0, 0.3], rng.normal(size=3)
        rotvec = rng.uniform(*KNOCK_DEG) * turn / np.linalg.norm(turn)
        shift = rng.uniform(*KNOCK_MM) * shift / np.linalg.norm(shift)
        if np.linalg.norm(np.cross(np.deg2rad(rotvec), home) + shift) >= KNOCK_HOME_MM:
            break
    return Drawn(
        [],
        (),
        expected="frame_step",
        finish=lambda m: knock_tracker(m, row, rotvec, shift),
        frame_row=row,
    )
