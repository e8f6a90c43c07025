"""Simulated standard tests: a controller drives the true robot to the ISO 9283 test poses or
through the ISO 230-2 leg targets (:mod:`hexcal.model.iso_tests`), and the instruments record.

Unlike the calibration session, which draws poses and derives readings, these tests are driven
in joint space, as a controller drives a real hexapod:

1. the **command**: the readings the controller sends — for ISO 9283 the readings its model
   (``controller``, a :class:`~hexcal.estimate.predict.LegModel`) gives for each test pose, for
   ISO 230-2 the target readings themselves;
2. the **servo** settles each leg it moves at the command within ``servo_sigma_mm`` (1σ): the
   encoder's true position. A leg whose command did not change stays where it was;
3. the **platform** goes where the true robot (``truth``: its geometry and hidden effects, as a
   LegModel — exactly the law the simulator's hidden effects follow) puts it for those true
   positions, the motion history (backlash) included;
4. the **instruments** add their noise: the tracker's to the pose, the encoders' to the reading.

The session's rows are free poses (leg 0) whose step is ``iso9283`` or ``iso230-2``, as the
procedure steps of those names record them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.estimate.predict import LegModel
from hexcal.io.measurements import Measurements
from hexcal.model.iso_tests import ISO230_CYCLES, ISO9283_CYCLES, iso230_targets, iso9283_sequence
from hexcal.model.robot import Robot
from hexcal.sim.inject import TRUE_PLAY_DEADBAND_MM
from hexcal.sim.simulate import NoiseModel


def true_model(
    truth: Robot, effects: Sequence[str] = (), values: np.ndarray | None = None
) -> LegModel:
    """The true robot as a predictor: its geometry and hidden effects (``values`` in the
    catalogue's units). A hidden backlash takes up the play on every real move (the
    simulator's dead band, :data:`~hexcal.sim.inject.TRUE_PLAY_DEADBAND_MM`)."""
    if "backlash" in effects and truth.backlash_deadband_mm is None:
        truth = truth.model_copy(update={"backlash_deadband_mm": TRUE_PLAY_DEADBAND_MM})
    vals = np.zeros(0) if values is None else np.asarray(values, float)
    return LegModel(truth, tuple(effects), vals)


def drive(
    truth: LegModel,
    commands: np.ndarray,
    rng: np.random.Generator,
    noise: NoiseModel,
    servo_sigma_mm: float,
    temperature: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(measured P (M, 3) mm, measured R (M, 3, 3), recorded readings (M, 6) mm) of the
    commands (M, 6) mm in order (module docstring, steps 2–4); ``temperature`` (M,) degC for a
    robot whose legs expand."""
    error = rng.normal(0.0, servo_sigma_mm, commands.shape)
    for m in range(1, len(commands)):  # a held leg keeps its place (and its error)
        held = commands[m] == commands[m - 1]
        error[m, held] = error[m - 1, held]
    true_readings = commands + error
    poses = truth.poses(true_readings, temperature=temperature, check_limits=False)
    return noise.apply(rng, poses.position, poses.rotation, true_readings)


def iso9283_commands(controller: LegModel, design: Robot, cycles: int = ISO9283_CYCLES):
    """(commands (M, 6) mm, step names (M,)): the readings ``controller`` sends for the test
    poses of ``design``'s cube, in the test's order."""
    _, P, R = iso9283_sequence(design, cycles)
    return controller.readings(P, R, check_limits=False), ["iso9283"] * len(P)


def iso230_commands(design: Robot, legs: Sequence[int] = range(1, 7), cycles: int = ISO230_CYCLES):
    """(commands (M, 6) mm, step names (M,)): each leg's test cycle in turn."""
    parts, names = [], []
    for leg in legs:
        readings, _ = iso230_targets(design, leg).sequence(cycles)
        parts.append(readings)
        names += ["iso230-2"] * len(readings)
    return np.concatenate(parts), names


def simulate_tests(
    truth: LegModel,
    design: Robot,
    rng: np.random.Generator,
    noise: NoiseModel,
    controller: LegModel | None = None,
    tests: Sequence[str] = ("iso9283", "iso230-2"),
    servo_sigma_mm: float | None = None,
    first_id: int = 1,
    t0: float = 0.0,
    temperature_c: float | None = None,
) -> Measurements:
    """A session of the standard ``tests`` on the true robot, driven by ``controller`` (default
    the design with no effects); ``servo_sigma_mm`` default: the encoders' noise; with
    ``temperature_c`` the structure stays at that temperature (the table gets the column)."""
    controller = controller or LegModel(design)
    servo = noise.sigma_reading_mm if servo_sigma_mm is None else servo_sigma_mm
    cmds, names = [], []
    if "iso9283" in tests:
        c, n = iso9283_commands(controller, design)
        cmds.append(c)
        names += n
    if "iso230-2" in tests:
        c, n = iso230_commands(design)
        cmds.append(c)
        names += n
    commands = np.concatenate(cmds)
    temp = None if temperature_c is None else np.full(len(commands), float(temperature_c))
    P, R, rho = drive(truth, commands, rng, noise, servo, temp)
    m = len(P)
    t = t0 + np.round(np.cumsum(rng.uniform(4.0, 8.0, m)), 3)
    return Measurements.from_arrays(
        P,
        Rotation.from_matrix(R),
        rho,
        step=np.array(names, dtype=object),
        t=t,
        pose_id=np.arange(first_id, first_id + m),
        temperature=temp,
    )
