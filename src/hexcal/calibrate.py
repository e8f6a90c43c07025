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


#: A fit whose χ²/dof exceeds this has not converged to the data's optimum (a linear seed too
#: far off, as the free-pose form is with few poses): it is tried again from the design.
RETRY_CHI2_PER_DOF = 10.0
#: The retried fit replaces the first only when its χ² is at most this fraction of it.
RETRY_GAIN = 0.9


def refine_from_seeds(P, R, rho, lin_a, lin_b, lin_off, design: Robot, fit_offsets, sig):
    """:func:`~hexcal.refine.refine` from the linear seed; when that fit fails (χ²/dof >
    :data:`RETRY_CHI2_PER_DOF`), again from the design's geometry, which replaces it (saying
    so in its notes) only when its χ² is clearly lower (:data:`RETRY_GAIN`).

    P (M, 3) mm, R (M, 3, 3), rho (M, 6) mm; seeds (6, 3), (6, 3), (6,) mm."""
    ref = refine(P, R, rho, lin_a, lin_b, lin_off, fit_offsets, sig)
    first = ref.chi2 / max(ref.dof, 1)
    if np.isfinite(first) and first <= RETRY_CHI2_PER_DOF:
        return ref
    alt = refine(P, R, rho, design.a, design.b, design.offsets, fit_offsets, sig)
    # Kept only when it escaped a local minimum: a model that misses an effect has a high
    # χ² from any start, and both starts then reach the same optimum (to rounding).
    if not alt.chi2 >= RETRY_GAIN * ref.chi2:  # NaN from the linear seed counts as failed too
        alt.notes.append(
            f"the fit from the linear seed stopped at χ²/dof {first:.1f}; started from the design's "
            f"geometry it reached {alt.chi2 / max(alt.dof, 1):.2f}: that fit is kept"
        )
        return alt
    return ref


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
    (name, home, pitch...); its points are a starting guess only when the fit from the linear
    seed fails (:func:`refine_from_seeds`). ``instruments``
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
        ref = refine_from_seeds(
            meas.position, R, meas.readings, a, b, off, design, model == 42, sig
        )
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
