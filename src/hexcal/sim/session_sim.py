"""A whole simulated calibration session: every leg's clamped sets, then free poses.

The true robot is the design perturbed as a real build would be (points by a few tenths of a
millimetre, offsets by up to a millimetre); the session is what the tracker and encoders would
report, in the order an operator records it.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.io.fileio import write_files_atomic
from hexcal.io.measurements import Measurements, measurements_to_csv_text
from hexcal.model.instruments import EncoderNoise, Instruments, TrackerNoise
from hexcal.model.robot import Robot
from hexcal.sim.simulate import LengthEffect, NoiseModel, PoseContext, PoseRanges, Simulator
from hexcal.vocabulary import Constraint

#: (constraint, Simulator method) in the order a leg's procedure records them.
PROCEDURE = (
    (Constraint.DIRECTION, "type_i"),
    (Constraint.DIRECTION_LENGTH, "type_ii"),
    (Constraint.LENGTH, "type_iii"),
)


@dataclass(frozen=True)
class SessionPlan:
    """How many poses of each kind, and how the true robot departs from the design."""

    n_type_i: int = 8
    n_type_ii: int = 8
    n_type_iii: int = 8
    n_free: int = 40
    point_sigma_mm: float = 0.3
    offset_halfwidth_mm: float = 1.0
    noise: NoiseModel = field(default_factory=lambda: NoiseModel(0.01, 0.002, 0.002))
    ranges: PoseRanges = field(default_factory=PoseRanges)
    #: Decimals the instruments report (position mm, quaternion, readings mm); None = exact.
    resolution: tuple[int, int, int] | None = (5, 9, 4)
    #: Structure temperature rise over the session, K (linear drift plus 0.05 K jitter).
    temperature_rise_k: float = 1.5


def perturbed_truth(design: Robot, rng: np.random.Generator, plan: SessionPlan) -> Robot:
    """The as-built robot: design points + N(0, point_sigma) mm, offsets + U(±halfwidth) mm."""
    a = design.a + rng.normal(0.0, plan.point_sigma_mm, (6, 3))
    b = design.b + rng.normal(0.0, plan.point_sigma_mm, (6, 3))
    off = design.offsets + rng.uniform(-plan.offset_halfwidth_mm, plan.offset_halfwidth_mm, 6)
    return design.with_geometry(a, b, off)


def simulate_session(
    design: Robot,
    seed: int,
    plan: SessionPlan = SessionPlan(),
    effects: Sequence[LengthEffect] = (),
    truth: Robot | None = None,
) -> tuple[Measurements, Robot]:
    """(measurement table, true robot) of one simulated session."""
    rng = np.random.default_rng(seed)
    truth = truth or perturbed_truth(design, rng, plan)
    sim = Simulator(truth, ranges=plan.ranges, noise=plan.noise, effects=effects)
    Ps, Rs, legs, cons, steps = [], [], [], [], []
    for k in range(6):
        for constraint, method in PROCEDURE:
            n = {"type_i": plan.n_type_i, "type_ii": plan.n_type_ii, "type_iii": plan.n_type_iii}[
                method
            ]
            if n == 0:
                continue
            P, R = getattr(sim, method)(k, (n,), rng)
            Ps.append(P)
            Rs.append(R)
            legs += [k + 1] * n
            cons += [constraint.value] * n
            steps += [f"leg{k + 1}-{constraint}"] * n
    if plan.n_free:
        P, R = sim.free((plan.n_free,), rng)
        Ps.append(P)
        Rs.append(R)
        legs += [0] * plan.n_free
        cons += [Constraint.FREE.value] * plan.n_free
        steps += ["free"] * plan.n_free
    P, R = np.concatenate(Ps), np.concatenate(Rs)
    m = len(P)
    t = np.round(np.cumsum(rng.uniform(8.0, 20.0, m)), 3)
    temperature = np.round(20.0 + plan.temperature_rise_k * t / t[-1] + rng.normal(0.0, 0.05, m), 2)
    ctx = PoseContext(P, R, t, temperature)
    Pm, Rm, rho = sim.measure(rng, P, R, ctx)
    q = Rotation.from_matrix(Rm).as_quat(scalar_first=True)
    if plan.resolution is not None:  # an instrument's resolution, as in the shared example
        dp, dq, dr = plan.resolution
        Pm, q, rho = np.round(Pm, dp), np.round(q, dq), np.round(rho, dr)
    meas = Measurements.from_arrays(
        Pm,
        q,
        rho,
        leg=np.array(legs),
        constraint=np.array(cons, dtype=object),
        step=np.array(steps, dtype=object),
        t=t,
        temperature=temperature,
    )
    return meas, truth


def _with_tests(meas, design, truth, effect, values, plan, tests, seed) -> Measurements:
    """``meas`` with the standard ``tests`` recorded after it, at its last temperature."""
    from hexcal.sim.metrology_sim import simulate_tests, true_model

    model = true_model(truth, (effect,) if effect else (), values)
    last_t = float(meas.temperature[-1]) if meas.temperature is not None else None
    extra = simulate_tests(
        model,
        design,
        np.random.default_rng([seed, 9283]),
        plan.noise,
        tests=tests,
        first_id=int(meas.pose_id.max()) + 1,
        t0=float(meas.t[-1]),
        temperature_c=last_t,
    )
    both = [meas, extra]
    temperature = None
    if last_t is not None:
        temperature = np.concatenate([meas.temperature, extra.temperature])
    return Measurements.from_arrays(
        np.concatenate([m.position for m in both]),
        np.concatenate([m.quaternion for m in both]),
        np.concatenate([m.readings for m in both]),
        leg=np.concatenate([m.leg for m in both]),
        constraint=np.concatenate([m.constraint for m in both]),
        step=np.concatenate([m.step for m in both]),
        t=np.concatenate([m.t for m in both]),
        pose_id=np.concatenate([m.pose_id for m in both]),
        temperature=temperature,
    )


def bump_poses(
    meas: Measurements, rng: np.random.Generator, n: int, size_mm: float = 0.5
) -> tuple[Measurements, np.ndarray]:
    """``meas`` with the measured position of ``n`` random poses displaced by ``size_mm`` in a
    random direction (a bumped tracker, a pose taken mid-move): (measurements, the rows
    displaced (n,), sorted)."""
    rows = np.sort(rng.choice(len(meas), n, replace=False))
    d = rng.normal(size=(n, 3))
    position = meas.position.copy()
    position[rows] += size_mm * d / np.linalg.norm(d, axis=1, keepdims=True)
    return dataclasses.replace(meas, position=position), rows


def truth_json(
    truth: Robot, seed: int, plan: SessionPlan, effect: str = "none beyond Model 42"
) -> str:
    """truth.json as in the shared example: the true geometry, the seed and the noise."""
    return (
        json.dumps(
            {
                "effect": effect,
                "seed": seed,
                "base_points": truth.a.tolist(),
                "platform_points": truth.b.tolist(),
                "leg_offsets": truth.offsets.tolist(),
                "noise": {
                    "kind": plan.noise.kind,
                    "position_mm": plan.noise.position_mm,
                    "angle_deg": plan.noise.orientation_deg,
                    "leg_mm": plan.noise.reading_mm,
                },
            },
            indent=2,
            allow_nan=False,
        )
        + "\n"
    )


def write_session_dir(
    outdir: str | Path,
    design: Robot,
    seed: int,
    plan: SessionPlan = SessionPlan(),
    effect: str | None = None,
    effect_scale: float = 1.0,
    pose_seed: int | None = None,
    effect_values: np.ndarray | None = None,
    tests: Sequence[str] = (),
) -> Path:
    """Write robot.json (design), measurements.csv, instruments.json and truth.json; with
    ``effect``, that registered effect is hidden at a realistic size, or with ``effect_values``
    (its true values go to truth.json). ``seed`` draws the robot (its truth and effect); ``pose_seed`` (default
    ``seed``) the poses and the noise, so another ``pose_seed`` is a second session of the same
    robot (for validation). ``tests`` (``iso9283``, ``iso230-2``) are appended after the
    session, driven in joint space by a controller running the design
    (:mod:`hexcal.sim.metrology_sim`)."""
    outdir = Path(outdir)
    rng = np.random.default_rng(seed)
    truth = perturbed_truth(design, rng, plan)
    hooks, label, values = [], "none beyond Model 42", None
    if effect:
        from hexcal.sim.inject import effect_hook, realistic_values

        if effect_values is None:
            values = realistic_values(effect, rng, truth, effect_scale)
        else:
            values = effect_scale * np.asarray(effect_values, float)
        hooks = [effect_hook(effect, values, truth)]
        label = effect
    poses = seed if pose_seed is None else pose_seed
    meas, truth = simulate_session(design, poses, plan, effects=hooks, truth=truth)
    if tests:
        meas = _with_tests(meas, design, truth, effect, values, plan, tests, poses)
    inst = Instruments(
        tracker=TrackerNoise(
            position_sigma_mm=plan.noise.sigma_position_mm,
            orientation_sigma_deg=float(np.rad2deg(plan.noise.sigma_orientation_rad)),
        ),
        encoders=EncoderNoise(reading_sigma_mm=plan.noise.sigma_reading_mm),
    )
    text = truth_json(truth, seed, plan, label)
    if effect and values is not None:
        from hexcal.effects import get_effect

        data = json.loads(text)
        names = [sp.name for sp in get_effect(effect).params(design)]
        data["effect_values"] = dict(zip(names, values.tolist(), strict=True))
        text = json.dumps(data, indent=2, allow_nan=False) + "\n"
    # The four files as one step: a failure (a full disk) leaves none of them, nor the folder.
    write_files_atomic(
        outdir,
        {
            "robot.json": design.to_json(),
            "measurements.csv": measurements_to_csv_text(meas),
            "instruments.json": inst.to_json(),
            "truth.json": text,
        },
    )
    return outdir
