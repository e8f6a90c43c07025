"""Simulated sessions of the verdict's hard cases, shared by the tests and
``benchmarks/diagnosis_rates.py``: several catalogue effects hiding at once, sessions at the
noise floor although something is hidden (what the geometry absorbs), one leg's zero jumping
mid-session, a stated noise too low, and effects outside the catalogue that the covariate
explorer must point at (the three here, and :mod:`hexcal.sim.foreign_cases`' more).

Every session is the Left Hand with a 20 kg platform, 184 poses, tracker noise 10 µm and
0.002°, encoder noise 2 µm, the temperature rising 5 K over the session (the instruments
stated as :data:`INSTRUMENTS` unless the case says otherwise); each draws its geometry, noise
and effect sizes from its seed.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from hexcal.io.measurements import Measurements
from hexcal.model.instruments import EncoderNoise, Instruments, TrackerNoise
from hexcal.model.robot import Robot
from hexcal.sim.foreign import joint_play, leg_sag, stroke_dent, stroke_quadratic
from hexcal.sim.foreign_cases import MORE, draw
from hexcal.sim.inject import effect_hook, realistic_values, zero_jump_hook
from hexcal.sim.robots import left_hand
from hexcal.sim.session_sim import SessionPlan, perturbed_truth, simulate_session
from hexcal.sim.simulate import NoiseModel

#: The noise the sessions state (1 σ): what the simulator draws, unless the case understates it.
INSTRUMENTS = Instruments(
    tracker=TrackerNoise(position_sigma_mm=0.01, orientation_sigma_deg=0.002),
    encoders=EncoderNoise(reading_sigma_mm=0.002),
)
#: The three catalogue effects hidden at once.
THREE = ("gain", "thermal", "backlash")
#: Effects outside the catalogue and the covariate each follows (:data:`MORE_FOREIGN`: more,
#: and the names accepted for each).
FOREIGN = {
    "stroke quadratic": "stroke",
    "stroke dent": "stroke",
    "joint play": "force",
}
#: More effects outside the catalogue (:mod:`hexcal.sim.foreign_cases`): one tuple per hidden
#: effect of the covariate names accepted for it; the session's own are
#: :attr:`HiddenCase.covariates`. ``tracker knocked`` has none: its verdict is ``frame_step``.
MORE_FOREIGN = MORE
#: Sessions at the floor although something is hidden: what the geometry absorbs.
ABSORBED = ("tracker scale", "leg sag")
#: How many times the true noise exceeds the stated one in the ``noise understated`` case.
NOISE_FACTOR = 2.0
#: The zero jump: its size, mm, and the share of the session on either side of it at least.
JUMP_MM = 0.05
JUMP_MARGIN = 0.25
#: The encoder error quadratic in the stroke reaches this at the stroke's ends, mm, about
#: this middle of the readings (mm).
QUADRATIC_MM = (0.03, 0.06)
STROKE_MIDDLE_MM = 60.0


@dataclass
class HiddenCase:
    """A simulated session and what is hidden in it."""

    meas: Measurements
    design: Robot
    instruments: Instruments
    case: str
    #: The verdict the diagnosis should reach (the last one of ``--auto`` for the chains)
    expected: str
    #: ``zero jump``: the leg (1-based), the row of the first pose after the jump, and how
    #: much longer the leg reads from then on (mm)
    jump_leg: int | None = None
    jump_row: int | None = None
    jump_mm: float | None = None
    #: ``foreign`` cases: the covariate the residual follows (the first effect's, for
    #: :data:`MORE_FOREIGN`)
    covariate: str | None = None
    #: ``foreign`` cases: one tuple per hidden effect, of the covariate names accepted for it
    #: in this session (the explorer's chain must name one of each)
    covariates: tuple[tuple[str, ...], ...] = ()
    #: ``tracker knocked``: the row (0-based, recording order) of the first pose after the knock
    frame_row: int | None = None
    #: ``noise understated``: the true noise over the stated
    noise_factor: float | None = None


def _start(seed: int, base: int) -> tuple[Robot, np.random.Generator, SessionPlan, Robot]:
    design = left_hand().model_copy(update={"platform_mass_kg": 20.0})
    rng = np.random.default_rng(base + seed)
    plan = SessionPlan(temperature_rise_k=5.0)
    return design, rng, plan, perturbed_truth(design, rng, plan)


def three_effects(seed: int) -> HiddenCase:
    """Gain, thermal expansion and backlash hidden together at their realistic sizes."""
    design, rng, plan, truth = _start(seed, 50_000)
    hooks = [effect_hook(e, realistic_values(e, rng, truth), truth) for e in THREE]
    meas, _ = simulate_session(design, seed, plan, effects=hooks, truth=truth)
    return HiddenCase(meas, design, INSTRUMENTS, "three effects", "none")


def absorbed(case: str, seed: int) -> HiddenCase:
    """``tracker scale``: the tracker's positions scaled by 30–100 ppm (a common scale error,
    which the geometry absorbs to below the noise at this size); ``leg sag``: each leg's joints
    0.1–0.2 mm·sin²θ closer than it reads (θ its angle from the vertical), which the joint
    positions absorb to 0.1 %."""
    design, rng, plan, truth = _start(seed, 60_000)
    hooks = []
    if case == "leg sag":
        hooks = [leg_sag(truth, rng.uniform(0.1, 0.2, 6))]
    elif case != "tracker scale":
        raise ValueError(f"no absorbed case {case!r}; the cases: {', '.join(ABSORBED)}")
    meas, _ = simulate_session(design, seed, plan, effects=hooks, truth=truth)
    if case == "tracker scale":
        scale = 1.0 + rng.choice([-1.0, 1.0]) * rng.uniform(30.0, 100.0) * 1e-6
        meas = dataclasses.replace(meas, position=meas.position * scale)
    return HiddenCase(meas, design, INSTRUMENTS, case, "none")


def zero_jump(seed: int) -> HiddenCase:
    """One leg's reading jumps by ±50 µm at a pose in the middle half of the session."""
    design, rng, plan, truth = _start(seed, 70_000)
    m = 6 * (plan.n_type_i + plan.n_type_ii + plan.n_type_iii) + plan.n_free
    leg = int(rng.integers(1, 7))
    row = int(rng.integers(int(JUMP_MARGIN * m), int((1 - JUMP_MARGIN) * m)))
    size = float(rng.choice([-1.0, 1.0]) * JUMP_MM)
    hooks = [zero_jump_hook(leg, row, size)]
    meas, _ = simulate_session(design, seed, plan, effects=hooks, truth=truth)
    return HiddenCase(meas, design, INSTRUMENTS, "zero jump", "zero_step", leg, row, size)


def noise_understated(seed: int) -> HiddenCase:
    """Nothing hidden, but the tracker and the encoders are :data:`NOISE_FACTOR` times noisier
    than the instruments state."""
    design, _, _, truth = _start(seed, 80_000)
    f = NOISE_FACTOR
    plan = SessionPlan(temperature_rise_k=5.0, noise=NoiseModel(0.01 * f, 0.002 * f, 0.002 * f))
    meas, _ = simulate_session(design, seed, plan, truth=truth)
    return HiddenCase(
        meas, design, INSTRUMENTS, "noise understated", "noise_understated", noise_factor=f
    )


def foreign(case: str, seed: int) -> HiddenCase:
    """An effect outside the catalogue (:data:`FOREIGN`): ``stroke quadratic`` (each encoder
    reading short by q·(reading − 60 mm)², 30–60 µm at the stroke's ends), ``stroke dent``
    (one leg reading 30–60 µm short around one place of its stroke, 3–6 mm wide), ``joint
    play`` (20–60 µm of play in each leg's joints, taken up one way or the other as its load
    reverses); or one of :data:`MORE_FOREIGN` (:func:`hexcal.sim.foreign_cases.draw`)."""
    if case in MORE:
        return _more(case, seed)
    design, rng, plan, truth = _start(seed, 90_000)
    if case == "stroke quadratic":
        ends = rng.choice([-1.0, 1.0], 6) * rng.uniform(*QUADRATIC_MM, 6)
        hooks = [stroke_quadratic(ends / 55.0**2, STROKE_MIDDLE_MM)]
    elif case == "stroke dent":
        leg = int(rng.integers(1, 7))
        depth = float(rng.choice([-1.0, 1.0]) * rng.uniform(0.03, 0.06))
        hooks = [stroke_dent(leg, float(rng.uniform(30, 90)), float(rng.uniform(3, 6)), depth)]
    elif case == "joint play":
        hooks = [joint_play(truth, rng.uniform(0.02, 0.06, 6))]
    else:
        cases = ", ".join([*FOREIGN, *MORE])
        raise ValueError(f"no foreign case {case!r}; the cases: {cases}")
    meas, _ = simulate_session(design, seed, plan, effects=hooks, truth=truth)
    cov = FOREIGN[case]
    return HiddenCase(
        meas, design, INSTRUMENTS, case, "unexplained", covariate=cov, covariates=((cov,),)
    )


def _more(case: str, seed: int) -> HiddenCase:
    design, rng, plan, truth = _start(seed, 100_000)
    n = 6 * (plan.n_type_i + plan.n_type_ii + plan.n_type_iii) + plan.n_free
    hidden = draw(case, rng, truth, n)
    meas, _ = simulate_session(design, seed, plan, effects=hidden.hooks, truth=truth)
    if hidden.finish is not None:
        meas = hidden.finish(meas)
    first = hidden.covariates[0][0] if hidden.covariates else None
    return HiddenCase(
        meas,
        design,
        INSTRUMENTS,
        case,
        hidden.expected,
        covariate=first,
        covariates=hidden.covariates,
        frame_row=hidden.frame_row,
    )
