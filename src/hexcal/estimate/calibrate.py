"""Whole-robot calibration: the linear methods per leg, then the weighted refinement.

The refinement runs twice: from the leg lengths alone (the seed, and the fallback), then with
each clamped step's own constraint added (:mod:`hexcal.estimate.clamp_rows`), which is the maximum
likelihood estimate when the clamps held. Whether they held is tested: the rows the clamps add
must not raise χ² by more than their degrees of freedom allow (:class:`ClampCheck`); when they
do, the leg-lengths fit is kept and the report says why.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hexcal.estimate.clamp_rows import ClampSteps
from hexcal.estimate.layout import ParameterLayout
from hexcal.estimate.predict import LegModel
from hexcal.estimate.quantiles import chi2_ppf
from hexcal.estimate.refine import FitStalled, Refinement, refine
from hexcal.estimate.solvers.whole_robot import Form, LinearCalibration, calibrate_linear
from hexcal.io.measurements import Measurements
from hexcal.model.instruments import Instruments
from hexcal.model.noise import NoiseSigmas
from hexcal.model.robot import Robot
from hexcal.vocabulary import ModelKind


@dataclass
class Calibration:
    """A calibrated robot and how it was obtained.

    ``robot`` carries the refined geometry (the linear one when ``refinement`` is None);
    ``methods`` says which linear method served each leg.
    """

    model: ModelKind
    robot: Robot
    linear: LinearCalibration
    refinement: Refinement | None
    residuals: np.ndarray  #: (M, 6) mm, measured length − predicted, at the final geometry
    linear_residuals: np.ndarray | None = None  #: (M, 6) mm at the linear seed
    effects: tuple[str, ...] = ()  #: catalogue effects fitted with the geometry
    clamp_check: ClampCheck | None = None  #: whether the clamps' constraints were used

    @property
    def methods(self) -> list[str]:
        return self.linear.methods

    @property
    def lengths_fit(self) -> Refinement | None:
        """The refinement from the leg lengths alone, from the linear seed (the one
        ``effect_fit.fit_model`` makes of a model without effects), when this calibration made
        it: None with effects, without refinement, or when the fit started from the design."""
        if self.effects or self.refinement is None:
            return None
        r = self.clamp_check.lengths_only if self.clamp_check is not None else self.refinement
        return None if r.from_design else r

    @property
    def model_name(self) -> str:
        """e.g. ``"Model 42 + gain"``."""
        return f"Model {self.model}" + "".join(f" + {e}" for e in self.effects)

    def leg_model(self) -> LegModel:
        """The calibrated model as a predictor: the geometry with the fitted effects, less
        those that belong to the session (a drifting tracker) rather than to the robot."""
        if self.refinement is None or not self.effects:
            return LegModel(self.robot)
        from hexcal.effects import get_effect

        r = self.refinement
        i = ParameterLayout(fit_offsets=self.model == ModelKind.M42).n_geometry
        keep: list[str] = []
        values: list[float] = []
        for e in self.effects:
            eff = get_effect(e)
            n = len(eff.params(self.robot))
            if not eff.of_the_session:
                keep.append(e)
                values.extend(r.x[i : i + n])
            i += n
        return LegModel(self.robot, tuple(keep), np.array(values))

    @property
    def session_effects(self) -> tuple[str, ...]:
        """Effects fitted as properties of the session, left out of :meth:`leg_model`."""
        from hexcal.effects import get_effect

        return tuple(e for e in self.effects if get_effect(e).of_the_session)

    def sigmas(self) -> dict[str, float]:
        """Standard deviation of every fitted parameter, by name (empty without refinement)."""
        r = self.refinement
        return {} if r is None else dict(zip(r.names, r.sigma.tolist(), strict=True))

    @property
    def rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.residuals**2)))


def leg_residuals(robot_a, robot_b, offsets, meas: Measurements) -> np.ndarray:
    """Reading + offset − geometric length, (M, 6) mm."""
    r = meas.rotations.as_matrix()
    v = meas.position[:, None, :] + np.einsum("mij,kj->mki", r, robot_b) - robot_a[None]
    return meas.readings + offsets - np.linalg.norm(v, axis=-1)


#: The clamps' rows are refused when their χ² excess has a p-value below this.
CLAMP_TEST_P = 1e-3


@dataclass(frozen=True)
class ClampCheck:
    """The test of the clamps' constraints against the leg lengths.

    ``excess`` is χ²(with clamps) − χ²(leg lengths only), ``df`` the rows the clamps add less
    their nuisance unknowns; ``ratio`` = (excess/df) / (χ²/dof of the lengths-only fit, at
    least 1 when the noise is stated), so that a model missing an effect, which raises both
    fits alike, does not fail it; ``limit`` its 1 − :data:`CLAMP_TEST_P` quantile.
    """

    steps: int
    excess: float
    df: int
    ratio: float
    limit: float
    used: bool
    lengths_only: Refinement  #: the fit without the clamp rows, for comparison
    #: The lengths-only fit already exceeds the stated noise (a missing effect): the clamps
    #: cannot be judged until the model fits.
    model_misfit: bool = False

    @property
    def text(self) -> str:
        head = (
            f"{self.steps} clamped steps add {self.df} degrees of freedom; χ² rose by "
            f"{self.excess:.1f} ({self.ratio:.2f}× their share, limit {self.limit:.2f})"
        )
        fit = self.lengths_only
        if self.used and self.model_misfit:
            return (
                f"clamp constraints used: {head}: the clamp rows fit as well as the leg lengths "
                f"do, but those alone leave χ²/dof {fit.chi2 / fit.dof:.2f} against the "
                "instruments' noise: the model misses an effect (the diagnosis names it)"
            )
        if self.used:
            return f"clamp constraints used: {head}: the clamps held"
        if self.model_misfit:
            return (
                f"clamp constraints not used: {head}, but the leg lengths alone already leave "
                f"χ²/dof {fit.chi2 / fit.dof:.2f} against the instruments' noise: the model misses an "
                "effect (the diagnosis names it) and the clamps can be judged only "
                "once it fits; the geometry is fitted from the leg lengths alone"
            )
        return (
            f"clamp constraints NOT used: {head}: the clamps did not hold what they claim (a "
            "clamp slipped or has play, a step mixes two clamp settings, or the wrong leg or "
            "constraint is recorded); the geometry is fitted from the leg lengths alone"
        )


def with_clamps(
    meas: Measurements, lengths: Refinement, fit_offsets: bool, sig, fixed_offsets, basis=None
) -> tuple[Refinement, ClampCheck | None]:
    """Refit with the clamp rows, seeded by the lengths-only fit ``lengths``; keep it if the
    clamps pass :class:`ClampCheck`. Returns (the kept fit, the check; None without clamped
    steps)."""
    steps = ClampSteps.from_table(meas.leg, meas.constraint, meas.step)
    if not len(steps):
        return lengths, None
    q = 0 if basis is None else basis.shape[-1]
    p0 = ParameterLayout(fit_offsets).n_geometry
    ref = refine(
        meas.position,
        meas.rotations.as_matrix(),
        meas.readings,
        lengths.a,
        lengths.b,
        lengths.offsets(fixed_offsets),
        fit_offsets,
        sig,
        basis=basis,
        basis_names=lengths.names[p0:] if q else None,
        theta0=lengths.x[p0:] if q else None,
        clamps=steps,
        # The seed is the converged lengths-only fit: the pose covariances evaluated there
        # differ from those at the solution by far less than the noise, so one pass suffices.
        passes=1,
    )
    # Rows in use = dof + unknowns; the clamp fit's unknowns include the steps' nuisance.
    rows_lengths = lengths.dof + len(lengths.x)
    rows_clamps = ref.dof + len(ref.x) + steps.n_nuisance
    df = rows_clamps - rows_lengths - steps.n_nuisance
    scale = lengths.chi2 / max(lengths.dof, 1)
    if sig is not None:
        scale = max(1.0, scale)
    excess = ref.chi2 - lengths.chi2
    ratio = excess / max(df, 1) / scale
    limit = float(chi2_ppf(1.0 - CLAMP_TEST_P, max(df, 1)) / max(df, 1))
    used = bool(np.isfinite(ratio) and ratio <= limit)
    misfit = lengths.exceeds_stated_noise
    check = ClampCheck(
        len(steps), float(excess), int(df), float(ratio), limit, used, lengths, misfit
    )
    return (ref if used else lengths), check


#: A fit whose χ²/dof exceeds this has not converged to the data's optimum (a linear seed too
#: far off, as the free-pose form is with few poses): it is tried again from the design.
RETRY_CHI2_PER_DOF = 10.0
#: The retried fit replaces the first only when its χ² is at most this fraction of it.
RETRY_GAIN = 0.9


def refine_from_seeds(P, R, rho, lin_a, lin_b, lin_off, design: Robot, fit_offsets, sig):
    """:func:`~hexcal.estimate.refine.refine` from the linear seed; when that fit fails (χ²/dof >
    :data:`RETRY_CHI2_PER_DOF`), again from the design's geometry, which replaces it (saying
    so in its notes) only when its χ² is clearly lower (:data:`RETRY_GAIN`).

    P (M, 3) mm, R (M, 3, 3), rho (M, 6) mm; seeds (6, 3), (6, 3), (6,) mm."""
    try:
        ref = refine(P, R, rho, lin_a, lin_b, lin_off, fit_offsets, sig)
    except FitStalled as stalled:
        # A linear seed far off (or thrown off by a bad pose) may not converge: the design's
        # geometry is the other start; if that stalls too, the stall is the answer.
        alt = refine(P, R, rho, design.a, design.b, design.offsets, fit_offsets, sig)
        alt.notes.append(
            f"the fit from the linear seed did not converge ({stalled}); started from the "
            "design's geometry it did: that fit is kept"
        )
        alt.from_design = True
        return alt
    first = ref.chi2 / max(ref.dof, 1)
    if np.isfinite(first) and first <= RETRY_CHI2_PER_DOF:
        return ref
    try:
        alt = refine(P, R, rho, design.a, design.b, design.offsets, fit_offsets, sig)
    except FitStalled:
        return ref
    # Kept only when it escaped a local minimum: a model that misses an effect has a high
    # χ² from any start, and both starts then reach the same optimum (to rounding).
    if not alt.chi2 >= RETRY_GAIN * ref.chi2:  # NaN from the linear seed counts as failed too
        alt.notes.append(
            f"the fit from the linear seed stopped at χ²/dof {first:.1f}; started from the design's "
            f"geometry it reached {alt.chi2 / max(alt.dof, 1):.2f}: that fit is kept"
        )
        alt.from_design = True
        return alt
    return ref


def calibrate(
    meas: Measurements,
    design: Robot,
    model: ModelKind = ModelKind.M42,
    instruments: Instruments | None = None,
    form: Form = "paper",
    do_refine: bool = True,
    effects: tuple[str, ...] | list[str] = (),
    clamps: bool = True,
) -> Calibration:
    """Calibrate Model 36 or 42 from a measurement table.

    ``design`` supplies the known offsets for Model 36 and every key that is not geometry
    (name, home, pitch...); its points are a starting guess only when the fit from the linear
    seed fails (:func:`refine_from_seeds`). ``instruments``
    gives the noise that weights the refinement; without it the level is estimated.
    ``effects`` (catalogue names) are fitted jointly with the geometry. ``clamps`` adds the
    clamped steps' own constraints to the refinement (:func:`with_clamps`; False: leg lengths
    only).
    """
    effects = tuple(e for e in effects if not (e == "offset" and model == ModelKind.M42))
    if effects:
        return _calibrate_with_effects(meas, design, model, instruments, effects, clamps)
    R = meas.rotations.as_matrix()
    lin = calibrate_linear(
        meas.position, R, meas.readings, meas.leg, meas.constraint, model, design.offsets, form
    )
    ref, check = None, None
    a, b, off = lin.a, lin.b, lin.offsets
    if do_refine:
        sig = NoiseSigmas.from_instruments(instruments) if instruments is not None else None
        ref = refine_from_seeds(
            meas.position, R, meas.readings, a, b, off, design, model == ModelKind.M42, sig
        )
        if clamps:
            ref, check = with_clamps(meas, ref, model == ModelKind.M42, sig, design.offsets)
        a, b, off = ref.a, ref.b, ref.offsets(off)
    robot = design.with_geometry(a, b, off)
    return Calibration(
        model,
        robot,
        lin,
        ref,
        leg_residuals(a, b, off, meas),
        leg_residuals(lin.a, lin.b, lin.offsets, meas),
        clamp_check=check,
    )


def _calibrate_with_effects(meas, design, model, instruments, effects, clamps) -> Calibration:
    from hexcal.effects import get_effect
    from hexcal.estimate.effect_fit import (
        GEOMETRY_PASSES,
        GEOMETRY_TOL,
        Problem,
        fit_model,
        fitted_robot,
    )

    sig = NoiseSigmas.from_instruments(instruments) if instruments is not None else None
    problem = Problem.build(meas, design, sig)
    full = (("offset",) if model == ModelKind.M42 else ()) + tuple(effects)
    fit = fit_model(problem, full, cross_validate=False)
    ref, check, basis = fit.refinement, None, fit.basis
    if clamps:
        ref, check = with_clamps(
            meas, fit.refinement, model == ModelKind.M42, sig, design.offsets, basis
        )
        # The clamp rows move the geometry: effects that use it are evaluated there again, so
        # the calibrated model predicts exactly what this fit did.
        if ref is not fit.refinement and any(get_effect(e).uses_geometry for e in effects):
            for _ in range(GEOMETRY_PASSES):
                new, _ = problem.stack(full, fitted_robot(problem.design, ref))
                change = np.max(np.abs(new - basis)) / max(np.max(np.abs(new)), 1e-300)
                if change < GEOMETRY_TOL:
                    break
                basis = new
                ref, check = with_clamps(
                    meas, fit.refinement, model == ModelKind.M42, sig, design.offsets, basis
                )
    lin = problem.linear42 if model == ModelKind.M42 else problem.linear36
    # problem.design: the design with the backlash dead band the fit used (from the stated
    # noise), so the calibrated model evaluates backlash as the fit did.
    robot = problem.design.with_geometry(ref.a, ref.b, ref.offsets(design.offsets))
    cal = Calibration(
        model, robot, lin, ref, ref.residuals, leg_residuals(lin.a, lin.b, lin.offsets, meas)
    )
    cal.effects = tuple(effects)
    cal.clamp_check = check
    return cal
