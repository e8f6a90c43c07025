"""Whole-robot calibration: the linear methods per leg, then the weighted refinement."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hexcal.instruments import Instruments
from hexcal.measurements import Measurements
from hexcal.noise import NoiseSigmas
from hexcal.refine import Refinement, refine
from hexcal.robot import Robot
from hexcal.solvers.whole_robot import Form, LinearCalibration, calibrate_linear


@dataclass
class Calibration:
    """A calibrated robot and how it was obtained.

    ``robot`` carries the refined geometry (the linear one when ``refinement`` is None);
    ``methods`` says which linear method served each leg.
    """

    model: int
    robot: Robot
    linear: LinearCalibration
    refinement: Refinement | None
    residuals: np.ndarray  #: (M, 6) mm, measured length − predicted, at the final geometry
    linear_residuals: np.ndarray | None = None  #: (M, 6) mm at the linear seed
    effects: tuple[str, ...] = ()  #: catalogue effects fitted with the geometry

    @property
    def methods(self) -> list[str]:
        return self.linear.methods

    @property
    def rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.residuals**2)))


def leg_residuals(robot_a, robot_b, offsets, meas: Measurements) -> np.ndarray:
    """Reading + offset − geometric length, (M, 6) mm."""
    r = meas.rotations.as_matrix()
    v = meas.position[:, None, :] + np.einsum("mij,kj->mki", r, robot_b) - robot_a[None]
    return meas.readings + offsets - np.linalg.norm(v, axis=-1)


def calibrate(
    meas: Measurements,
    design: Robot,
    model: int = 42,
    instruments: Instruments | None = None,
    form: Form = "paper",
    do_refine: bool = True,
    effects: tuple[str, ...] | list[str] = (),
) -> Calibration:
    """Calibrate Model 36 or 42 from a measurement table.

    ``design`` supplies the known offsets for Model 36 and every key that is not geometry
    (name, home, pitch...); its points are never used as a starting guess. ``instruments``
    gives the noise that weights the refinement; without it the level is estimated.
    ``effects`` (catalogue names) are fitted jointly with the geometry.
    """
    effects = tuple(e for e in effects if not (e == "offset" and model == 42))
    if effects:
        return _calibrate_with_effects(meas, design, model, instruments, effects)
    R = meas.rotations.as_matrix()
    lin = calibrate_linear(
        meas.position, R, meas.readings, meas.leg, meas.constraint, model, design.offsets, form
    )
    ref = None
    a, b, off = lin.a, lin.b, lin.offsets
    if do_refine:
        sig = NoiseSigmas.from_instruments(instruments) if instruments is not None else None
        ref = refine(meas.position, R, meas.readings, a, b, off, model == 42, sig)
        a, b, off = ref.a, ref.b, ref.offsets(off)
    robot = design.with_geometry(a, b, off)
    return Calibration(
        model,
        robot,
        lin,
        ref,
        leg_residuals(a, b, off, meas),
        leg_residuals(lin.a, lin.b, lin.offsets, meas),
    )


def _calibrate_with_effects(meas, design, model, instruments, effects) -> Calibration:
    from hexcal.diagnosis.model import Problem, fit_model

    sig = NoiseSigmas.from_instruments(instruments) if instruments is not None else None
    problem = Problem.build(meas, design, sig)
    full = (("offset",) if model == 42 else ()) + tuple(effects)
    fit = fit_model(problem, full, cross_validate=False)
    ref = fit.refinement
    lin = problem.linear42 if model == 42 else problem.linear36
    robot = design.with_geometry(ref.a, ref.b, ref.offsets(design.offsets))
    cal = Calibration(
        model, robot, lin, ref, fit.residuals, leg_residuals(lin.a, lin.b, lin.offsets, meas)
    )
    cal.effects = tuple(effects)
    return cal
