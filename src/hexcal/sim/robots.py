"""Robots beyond the Left Hand for simulated sessions: a precision hexapod (strokes of ± 8 mm,
µm instruments, moves of a few tens of µm) and a large motion base (legs about 2.1 m, a laser
tracker), with the sessions a lab would record on them.

They are the Left Hand's geometry scaled, so the pose-set shapes the project's defaults were
chosen for carry over; what changes is what matters to the diagnosis: the size of the moves
against the instruments' noise, and the size of the robot against the effects.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.io.measurements import Measurements
from hexcal.model.instruments import EncoderNoise, Instruments, TrackerNoise
from hexcal.model.robot import Robot
from hexcal.sim.inject import effect_hook
from hexcal.sim.session_sim import SessionPlan, perturbed_truth
from hexcal.sim.simulate import NoiseModel, PoseContext, PoseRanges, Simulator


def left_hand() -> Robot:
    """The seed paper's Left Hand robot (§4 table, converted to mm)."""
    text = resources.files("hexcal").joinpath("data/left_hand.json").read_text(encoding="utf-8")
    return Robot.model_validate_json(text)


# -- a precision hexapod ----------------------------------------------------------------------
#: 1 µm on every reading and on the tracker's position, 0.0002° on its orientation (1σ).
PRECISE_NOISE = NoiseModel(0.001, 0.0002, 0.001)
PRECISE_INSTRUMENTS = Instruments(
    tracker=TrackerNoise(position_sigma_mm=0.001, orientation_sigma_deg=0.0002),
    encoders=EncoderNoise(reading_sigma_mm=0.001),
)


def precise_design() -> Robot:
    """The Left Hand at half size: legs about 106 mm, home 100 mm above the base."""
    lh = left_hand()
    home = lh.home.model_copy(update={"position": [0.0, 0.0, 100.0]})
    return lh.with_geometry(0.5 * lh.a, 0.5 * lh.b, 0.5 * lh.offsets).model_copy(
        update={"name": "precision-hexapod", "home": home}
    )


def move_legs(
    robot: Robot, P: np.ndarray, R: np.ndarray, dl: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The pose near ``(P (3,) mm, R (3, 3))`` whose legs are ``dl`` (6,) mm longer (Newton on
    the leg lengths; four steps reach 1e-12 mm for moves of tens of µm)."""

    def legs(P: np.ndarray, R: np.ndarray) -> np.ndarray:
        return P + robot.b @ R.T - robot.a  # (6, 3)

    target = np.linalg.norm(legs(P, R), axis=1) + dl
    for _ in range(4):
        v = legs(P, R)
        length = np.linalg.norm(v, axis=1)
        n = v / length[:, None]
        jac = np.concatenate([n, np.cross(robot.b @ R.T, n)], axis=1)
        dx = np.linalg.solve(jac, target - length)
        P, R = P + dx[:3], Rotation.from_rotvec(dx[3:]).as_matrix() @ R
    return P, R


@dataclass(frozen=True)
class PreciseSession:
    meas: Measurements
    design: Robot
    truth: Robot
    #: The hidden backlash per leg (6,) mm; zeros when none was hidden.
    beta: np.ndarray


def precise_session(
    seed: int, clusters: int = 40, steps: int = 3, backlash: bool = True
) -> PreciseSession:
    """A precision hexapod's session: ``clusters`` poses spread over the workspace (leg strokes
    about ± 8 mm), each followed by ``steps`` small moves where each leg moves by 12–40 µm
    either way or (one time in four) stays still. With ``backlash``, 2–5 µm of play per leg
    acting on every real move (the truth's dead band 0.1 µm); noise 1 µm."""
    design = precise_design()
    rng = np.random.default_rng(seed)
    truth = perturbed_truth(design, rng, SessionPlan(point_sigma_mm=0.05, offset_halfwidth_mm=0.2))
    beta = rng.uniform(0.002, 0.005, 6) if backlash else np.zeros(6)
    sim = Simulator(
        truth,
        ranges=PoseRanges(box_mm=(6.0, 6.0, 6.0), tilt_deg=3.0),
        noise=PRECISE_NOISE,
        effects=[effect_hook("backlash", beta, truth)] if backlash else [],
    )
    starts = sim.free((clusters,), rng)
    Ps, Rs = [], []
    for P, R in zip(*starts, strict=True):
        Ps.append(P)
        Rs.append(R)
        for _ in range(steps):
            size = rng.uniform(0.012, 0.040, 6) * rng.choice([-1.0, 1.0], 6)
            P, R = move_legs(truth, P, R, size * (rng.random(6) < 0.75))
            Ps.append(P)
            Rs.append(R)
    P, R = np.array(Ps), np.array(Rs)
    t = np.cumsum(rng.uniform(5.0, 10.0, len(P)))
    Pm, Rm, rho = sim.measure(rng, P, R, PoseContext(P, R, t, np.full(len(P), 20.0)))
    meas = Measurements.from_arrays(Pm, Rotation.from_matrix(Rm), rho, t=t)
    return PreciseSession(meas, design, truth, beta)


# -- a large motion base ----------------------------------------------------------------------
#: A laser tracker with a 6-DOF probe at a few metres: 30 µm, 0.002°; encoders 5 µm (1σ).
MOTION_BASE_NOISE = NoiseModel(0.03, 0.002, 0.005)
MOTION_BASE_INSTRUMENTS = Instruments(
    tracker=TrackerNoise(position_sigma_mm=0.03, orientation_sigma_deg=0.002),
    encoders=EncoderNoise(reading_sigma_mm=0.005),
)
MOTION_BASE_MASS_KG = 1500.0


def motion_base_design() -> Robot:
    """The Left Hand at ten times its size: legs about 2.1 m, home 2 m above the base, a
    1500 kg platform (a driving or flight simulator's cabin)."""
    lh = left_hand()
    home = lh.home.model_copy(update={"position": [0.0, 0.0, 2000.0]})
    return lh.with_geometry(10.0 * lh.a, 10.0 * lh.b, 10.0 * lh.offsets).model_copy(
        update={
            "name": "motion-base",
            "home": home,
            "platform_mass_kg": MOTION_BASE_MASS_KG,
            "leadscrew_pitch_mm": 20.0,
        }
    )


def motion_base_plan(temperature_rise_k: float = 5.0) -> SessionPlan:
    """The default session (8 + 8 + 8 poses per leg, 40 free) moved as a lab would move this
    robot: leg strokes ± 300 mm, a ± 200 mm box; the as-built robot off its drawing by 1 mm per
    point and up to 3 mm per offset."""
    return SessionPlan(
        point_sigma_mm=1.0,
        offset_halfwidth_mm=3.0,
        noise=MOTION_BASE_NOISE,
        ranges=PoseRanges(stroke_mm=300.0, box_mm=(200.0, 200.0, 200.0)),
        resolution=(4, 9, 4),
        temperature_rise_k=temperature_rise_k,
    )


def motion_base_values(name: str, rng: np.random.Generator, scale: float = 1.0) -> np.ndarray:
    """Realistic sizes on the motion base where the Left Hand's do not carry over: compliance
    0.01–0.03 µm/N (25–75 µm of sag per leg under 1500 kg, stiff legs of 30–100 N/µm)."""
    if name == "compliance":
        return scale * rng.uniform(0.01, 0.03, 1)
    raise ValueError(f"the Left Hand's realistic sizes serve for {name!r}")
