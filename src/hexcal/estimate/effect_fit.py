"""A model = Model 36 geometry + a set of catalogue effects (``offset`` makes it Model 42),
fitted jointly by the weighted refinement, with cross-validation on held-out poses."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from hexcal.effects import CATALOGUE, EffectData, ParamSpec, get_effect
from hexcal.effects.backlash import deadband_for_noise
from hexcal.effects.covariates import numeric_columns
from hexcal.estimate.accuracy import PoseAccuracy, PoseErrors, pose_errors, pose_floor
from hexcal.estimate.folds import fold_fits
from hexcal.estimate.layout import ParameterLayout
from hexcal.estimate.leg_rows import LegData, leg_residuals
from hexcal.estimate.predict import LegModel
from hexcal.estimate.refine import Refinement, refine
from hexcal.estimate.solvers.whole_robot import LinearCalibration, calibrate_linear
from hexcal.io.measurements import Measurements
from hexcal.model.noise import DEFAULT_SIGMAS, NoiseSigmas, leg_covariance
from hexcal.model.robot import Robot
from hexcal.vocabulary import ModelKind

#: Folds of the random k-fold and of the time-blocked cross-validation.
K_FOLDS = 5


@dataclass(frozen=True)
class ParamRow:
    """A fitted parameter in its spec unit: value, standard deviation, 95 % half-width.

    ``physical`` says whether the value lies within its plausible range (the robot's prior,
    robot.json ``plausible``, else the catalogue's): a value outside is flagged with what it
    means (the fit's notes), never a verdict."""

    name: str
    value: float
    sigma: float
    ci95: float
    unit: str
    plausible: tuple[float, float] | None
    status: str

    @property
    def physical(self) -> bool:
        if self.plausible is None:
            return True
        lo, hi = self.plausible
        return bool(lo <= self.value <= hi)


@dataclass
class ModelFit:
    """One fitted model and how it compares with the measurements.

    residuals (M, 6) mm: reading − predicted reading (predicted from the measured pose).
    """

    effects: tuple[str, ...]
    refinement: Refinement
    residuals: np.ndarray
    params: list[ParamRow]
    basis_names: list[str]
    cv_rms_mm: float = float("nan")
    cv_blocked_rms_mm: float = float("nan")
    cv_residuals: np.ndarray | None = None  #: (M, 6) held-out residuals, random folds
    cv_blocked_residuals: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)
    #: (M, 6, q) the effects' basis as fitted: at the fitted geometry for effects that use it
    basis: np.ndarray | None = None
    #: The random folds' held-out poses and the parameter vector fitted without them
    folds: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)

    @property
    def model_name(self) -> str:
        base = "Model 42" if "offset" in self.effects else "Model 36"
        extra = [e for e in self.effects if e != "offset"]
        return base + ("".join(f" + {e}" for e in extra))

    @property
    def rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.residuals**2)))

    @property
    def rms_per_leg(self) -> np.ndarray:
        return np.sqrt(np.mean(self.residuals**2, axis=0))

    @property
    def held_out_residuals(self) -> np.ndarray:
        """(M, 6) mm, the random folds' held-out residuals; a fit made without
        cross-validation has none, and asking for them is a bug."""
        if self.cv_residuals is None:
            raise ValueError(f"{self.model_name} was fitted without cross-validation")
        return self.cv_residuals

    @property
    def cv_rms_per_leg(self) -> np.ndarray:
        return np.sqrt(np.mean(self.held_out_residuals**2, axis=0))

    def rms_per_step(self, steps: np.ndarray) -> dict[str, dict[str, float]]:
        """{step: {"rms_mm", "cv_rms_mm", "poses"}} in recording order; steps (M,) labels."""
        out = {}
        held = self.held_out_residuals
        for step in dict.fromkeys(steps.tolist()):
            m = steps == step
            out[str(step)] = {
                "rms_mm": float(np.sqrt(np.mean(self.residuals[m] ** 2))),
                "cv_rms_mm": float(np.sqrt(np.mean(held[m] ** 2))),
                "poses": int(m.sum()),
            }
        return out

    @property
    def n_params(self) -> int:
        return len(self.refinement.x)

    @property
    def chi2(self) -> float:
        return self.refinement.chi2

    @property
    def dof(self) -> int:
        return self.refinement.dof

    def nonphysical(self) -> list[ParamRow]:
        return [p for p in self.params if not p.physical]

    def leg_model(self, design: Robot) -> LegModel:
        """The fitted model as a predictor (geometry, offsets and effects)."""
        return leg_model(design, self.effects, self.refinement.x)


def leg_model(design: Robot, effects: tuple[str, ...], x: np.ndarray) -> LegModel:
    """A predictor from a parameter vector laid out as the refinement's
    (:class:`~hexcal.estimate.layout.ParameterLayout`): a (18), b (18), the offsets (6) when
    ``offset`` is among ``effects``, then the other effects' parameters."""
    lay = ParameterLayout.of_vector(x, "offset" in effects)
    robot = design.with_geometry(lay.a(x), lay.b(x), lay.offsets(x, design.offsets))
    return LegModel(robot, effects, lay.effects(x))


@dataclass
class Problem:
    """Everything a fit needs, computed once per session: arrays, effect data, linear seed."""

    meas: Measurements
    design: Robot
    sigmas: NoiseSigmas | None
    linear42: LinearCalibration
    data: EffectData
    _bases: dict[str, np.ndarray] = field(default_factory=dict)
    _missing: dict[str, str | None] = field(default_factory=dict)
    #: The drawing's pose accuracy, computed once per session (see :func:`design_accuracy`)
    design_pose_accuracy: PoseAccuracy | None = None
    design_errors: PoseErrors | None = None
    _linear36: LinearCalibration | None = None

    @classmethod
    def build(
        cls,
        meas: Measurements,
        design: Robot,
        sigmas: NoiseSigmas | None,
        linear42: LinearCalibration | None = None,
    ) -> Problem:
        """The problem of a session. With the encoders' noise stated and no
        ``backlash_deadband_mm`` in the design, the design gets the dead band of that noise
        (:func:`~hexcal.effects.backlash.deadband_for_noise`): every model fitted here, and the
        calibrated model built from ``problem.design``, then evaluates backlash alike.
        ``linear42``: Model 42's linear seed (the paper's forms) when the caller has it."""
        design = with_deadband(design, sigmas)
        R = meas.rotations.as_matrix()
        if linear42 is None:
            args = (meas.position, R, meas.readings, meas.leg, meas.constraint)
            linear42 = calibrate_linear(*args, ModelKind.M42, design.offsets)
        data = EffectData(
            meas.readings,
            meas.position,
            R,
            meas.t,
            meas.temperature,
            design,
            linear42.a,
            linear42.b,
            columns=numeric_columns(meas.extra),
            step=np.asarray(meas.step, dtype=object),
        )
        return cls(meas, design, sigmas, linear42, data)

    @property
    def linear36(self) -> LinearCalibration:
        """Model 36's linear seed (the drawing's offsets), made when first asked for: a Model
        42 diagnosis never needs it."""
        if self._linear36 is None:
            m = self.meas
            self._linear36 = calibrate_linear(
                m.position,
                self.R,
                m.readings,
                m.leg,
                m.constraint,
                ModelKind.M36,
                self.design.offsets,
            )
        return self._linear36

    @property
    def R(self) -> np.ndarray:
        return self.data.rotation

    def basis(self, name: str) -> np.ndarray:
        """(M, 6, p) basis of an effect over the whole session (history-dependent effects need
        the whole recording order, so folds take rows of this)."""
        if name not in self._bases:
            self._bases[name] = get_effect(name).basis(self.data)
        return self._bases[name]

    def missing(self, name: str) -> str | None:
        """Why these data cannot carry effect ``name`` (None when they can); asked once."""
        if name not in self._missing:
            self._missing[name] = get_effect(name).missing(self.data)
        return self._missing[name]

    def stack(
        self, effects: tuple[str, ...], robot: Robot | None = None
    ) -> tuple[np.ndarray, list[ParamSpec]]:
        """(M, 6, q) basis of ``effects`` (``offset`` excluded) and their specs; effects that use
        the geometry are evaluated at ``robot``'s (None: at the linear seed)."""
        specs = _specs(effects, self.design)
        data = None if robot is None else self.data.at_geometry(robot)
        cols = []
        for e in effects:
            if e == "offset":
                continue
            eff = get_effect(e)
            cols.append(
                eff.basis(data) if data is not None and eff.uses_geometry else self.basis(e)
            )
        m = len(self.meas)
        return (np.concatenate(cols, axis=-1) if cols else np.zeros((m, 6, 0))), specs


def with_deadband(design: Robot, sigmas: NoiseSigmas | None) -> Robot:
    """``design`` with ``backlash_deadband_mm`` set from the stated encoder noise, unless it
    states one itself or the noise is unknown (then the effect's fallback applies)."""
    if design.backlash_deadband_mm or sigmas is None or not sigmas.reading_mm > 0:
        return design
    return design.model_copy(update={"backlash_deadband_mm": deadband_for_noise(sigmas.reading_mm)})


def _specs(effects: tuple[str, ...], robot: Robot) -> list[ParamSpec]:
    return [s for e in effects if e != "offset" for s in get_effect(e).params(robot)]


def fitted_robot(design: Robot, ref: Refinement) -> Robot:
    """The design with a refinement's geometry and offsets (every other key kept)."""
    return design.with_geometry(ref.a, ref.b, ref.offsets(design.offsets))


#: Effects that use the geometry are re-evaluated at the fitted one until their basis moves by
#: less than this (mm per unit parameter, relative): then the stored model predicts what the fit did.
GEOMETRY_TOL = 1e-12
#: At most this many re-evaluations (the basis depends on the geometry weakly: two suffice).
GEOMETRY_PASSES = 4


def fit_model(
    problem: Problem,
    effects: tuple[str, ...] | list[str],
    cross_validate: bool = True,
    seed_fit: ModelFit | None = None,
    refinement: Refinement | None = None,
) -> ModelFit:
    """Fit the geometry with ``effects`` jointly; cross-validate on held-out poses.

    Seeded by the linear methods (Model 42's when ``offset`` is in the model), or by
    ``seed_fit``'s geometry when given (a model one effect larger than a fitted one).
    ``refinement``: that very fit, already made elsewhere (``calibrate``'s from the same linear
    seed, of a model without effects): it is used as it is, not made again.
    """
    effects = tuple(dict.fromkeys(effects))
    for e in effects:
        if e not in CATALOGUE:
            get_effect(e)  # raises with the catalogue listed
        why = problem.missing(e)
        if why:
            raise ValueError(f"effect {e!r} cannot be fitted to these data: {why}")
    fit_offsets = "offset" in effects
    basis, specs = problem.stack(effects)
    lin = problem.linear42 if fit_offsets else problem.linear36
    a0, b0, off0 = lin.a, lin.b, lin.offsets if fit_offsets else problem.design.offsets
    theta0 = None
    if seed_fit is not None:
        r = seed_fit.refinement
        a0, b0 = r.a, r.b
        if fit_offsets:
            off0 = r.offsets(problem.design.offsets)
        theta0 = np.array([r.value(s.name) if s.name in r.names else 0.0 for s in specs])
    names = [s.name for s in specs]
    if refinement is not None:
        if names:
            raise ValueError("a refinement made elsewhere is reused for models without effects")
        ref = refinement
    else:
        ref = refine(
            problem.meas.position,
            problem.R,
            problem.meas.readings,
            a0,
            b0,
            off0,
            fit_offsets,
            problem.sigmas,
            basis=basis,
            basis_names=names,
            theta0=theta0,
        )
    if any(get_effect(e).uses_geometry for e in effects if e != "offset"):
        ref, basis = _at_fitted_geometry(problem, effects, ref, basis, fit_offsets, names)
    fit = ModelFit(effects, ref, ref.residuals, _param_rows(ref, specs, problem.design), names)
    fit.basis = basis
    if cross_validate:
        cross_validation(problem, fit, basis)
    fit.notes = [out_of_range_note(p, problem.design) for p in fit.nonphysical()] + ref.notes
    return fit


def cross_validated(problem: Problem, fit: ModelFit) -> ModelFit:
    """A fit made without cross-validation (``fit_model(..., cross_validate=False)``) with it
    added: a copy, the fit itself not made again (the outlier search's fit, reused)."""
    if fit.basis is None:
        raise ValueError(f"{fit.model_name} has no basis recorded: fit it with fit_model")
    out = replace(fit, folds=[], notes=list(fit.notes))
    cross_validation(problem, out, fit.basis)
    return out


def out_of_range_note(p: ParamRow, design: Robot) -> str:
    """The note of a value outside its plausible range: what the value means physically and
    what to check (the effect's :meth:`~hexcal.effects.base.Effect.meaning`), or that the range
    can be widened — a flag for the user, not a verdict."""
    if p.plausible is None:
        raise ValueError(f"{p.name} has no plausible range to be outside of")
    lo, hi = p.plausible
    effect = "offset" if p.name.startswith("offset") else p.name.split(".")[0]
    meaning = get_effect(effect).meaning(p.name, p.value, design)
    return (
        f"{p.name} = {_num(p.value)} {p.unit} is outside its plausible range "
        f"[{_num(lo)}, {_num(hi)}] {p.unit}: {meaning}, or set plausible in robot.json if this "
        "hardware allows it"
    )


def _num(v: float) -> str:
    """A value to 3 significant digits from 1000 up, thousands separated (−54,700), else to 4
    (609.8), with a true minus sign."""
    v = float(f"{v:.3g}") if abs(v) >= 1000 else v
    text = f"{v:,.0f}" if abs(v) >= 1000 else f"{v:.4g}"
    return text.replace("-", "−")


def _at_fitted_geometry(problem, effects, ref, basis, fit_offsets, names):
    """Refit with the geometry-dependent effects evaluated at the fitted geometry, until it
    settles (:data:`GEOMETRY_TOL`)."""
    for _ in range(GEOMETRY_PASSES):
        new, _ = problem.stack(effects, fitted_robot(problem.design, ref))
        change = np.max(np.abs(new - basis)) / max(np.max(np.abs(new)), 1e-300)
        basis = new
        if change < GEOMETRY_TOL:
            break
        ref = refine(
            problem.meas.position,
            problem.R,
            problem.meas.readings,
            ref.a,
            ref.b,
            ref.offsets(problem.design.offsets),
            fit_offsets,
            problem.sigmas,
            basis=basis,
            basis_names=names,
            theta0=ref.layout.effects(ref.x),
            passes=1,
        )
    return ref, basis


def _param_rows(ref: Refinement, specs: list[ParamSpec], design: Robot) -> list[ParamRow]:
    """Effect parameters in their spec units; offsets judged by their departure from design."""
    by_name = {s.name: s for s in specs}
    offsets = {s.name: s.plausible for s in get_effect("offset").params(design)}
    rows = []
    for i, name in enumerate(ref.names):
        spec = by_name.get(name)
        if spec is not None:
            unit, plausible = spec.unit, spec.plausible
        elif name in offsets:
            d = design.offsets[int(name[6:]) - 1]
            off_lo, off_hi = offsets[name]
            unit, plausible = "mm", (d + off_lo, d + off_hi)
        else:
            unit, plausible = "mm", None
        rows.append(
            ParamRow(
                name,
                float(ref.x[i]),
                float(ref.sigma[i]),
                float(ref.ci95[i]),
                unit,
                plausible,
                ref.status[i],
            )
        )
    return rows


def _folds(m: int, blocked: bool, seed: int = 0) -> list[np.ndarray]:
    if blocked:
        return np.array_split(np.arange(m), K_FOLDS)
    perm = np.random.default_rng(seed).permutation(m)
    return [np.sort(f) for f in np.array_split(perm, K_FOLDS)]


def cross_validation(problem: Problem, fit: ModelFit, basis: np.ndarray) -> None:
    """Held-out residuals over whole poses: random folds and folds blocked in time.

    Each fold is refitted from the full fit's solution (one covariance pass, evaluated there);
    the held-out poses' residuals use the fold's parameters. The folds share the evaluations
    at the full fit's solution (:func:`hexcal.estimate.folds.fold_fits`).
    """
    ref = fit.refinement
    fit_offsets = "offset" in fit.effects
    m = len(problem.meas)
    lay = ParameterLayout.of_vector(ref.x, fit_offsets)
    d = LegData.of(
        problem.meas.position,
        problem.R,
        problem.meas.readings,
        problem.design.offsets,
        basis if basis.shape[-1] else None,
    )
    sig = problem.sigmas if problem.sigmas is not None else DEFAULT_SIGMAS
    partitions = [_folds(m, False), _folds(m, True)]
    fitted = fold_fits(d, ref.x, lay, sig, partitions)
    for blocked, part, xs in zip((False, True), partitions, fitted, strict=True):
        held = np.zeros((m, 6))
        for test, x in zip(part, xs, strict=True):
            held[test] = -leg_residuals(x[None], d.take(test), lay)[0]
            if not blocked:
                fit.folds.append((test, x))
        if blocked:
            fit.cv_blocked_residuals = held
            fit.cv_blocked_rms_mm = float(np.sqrt(np.mean(held**2)))
        else:
            fit.cv_residuals = held
            fit.cv_rms_mm = float(np.sqrt(np.mean(held**2)))


def heldout_pose_errors(problem: Problem, fit: ModelFit) -> PoseErrors:
    """Each pose's pose error by the model of the random fold that did not see it (the folds
    of :func:`cross_validation`): its pose from its readings against the tracker's."""
    m = len(problem.meas)
    pos, ang, closed = np.zeros(m), np.zeros(m), np.ones(m, bool)
    for test, x in fit.folds:
        e = pose_errors(leg_model(problem.design, fit.effects, x), problem.meas, test)
        pos[test], ang[test], closed[test] = e.position_mm, e.orientation_deg, e.closed
    return PoseErrors(pos, ang, closed)


def heldout_accuracy(
    problem: Problem,
    fit: ModelFit,
    sig: NoiseSigmas | None = None,
    errors: PoseErrors | None = None,
) -> PoseAccuracy:
    """Pose accuracy on held-out poses (:func:`heldout_pose_errors`, or ``errors`` already
    computed); with ``sig``, the floor the noise alone gives."""
    errors = heldout_pose_errors(problem, fit) if errors is None else errors
    r = fit.refinement
    floor = None if sig is None else pose_floor(r.a, r.b, problem.meas, sig)
    return PoseAccuracy.of(fit.model_name, errors, True, fit.cv_rms_mm, floor)


def design_pose_errors(problem: Problem) -> PoseErrors:
    """Every pose's pose error with the drawing (robot.json as designed, nothing fitted)."""
    if problem.design_errors is None:
        problem.design_errors = pose_errors(LegModel(problem.design), problem.meas)
    return problem.design_errors


def design_accuracy(problem: Problem, sig: NoiseSigmas | None = None) -> PoseAccuracy:
    """Pose accuracy of the drawing (robot.json as designed, nothing fitted) on every pose."""
    model = LegModel(problem.design)
    leg_rms = float(np.sqrt(np.mean(model.residuals(problem.meas) ** 2)))
    d = problem.design
    floor = None if sig is None else pose_floor(d.a, d.b, problem.meas, sig)
    return PoseAccuracy.of("design (drawing)", design_pose_errors(problem), False, leg_rms, floor)


def noise_floor(problem: Problem, fit: ModelFit) -> np.ndarray:
    """(M, 6) mm: the standard deviation of each residual that the stated noise alone gives,
    propagated through the fitted geometry (the diagonal of each pose's 6×6 covariance)."""
    if problem.sigmas is None:
        raise ValueError("the noise floor needs the instruments' stated noise")
    r = fit.refinement
    cov = leg_covariance(r.a, r.b, problem.meas.position, problem.R, problem.sigmas)
    return np.sqrt(np.einsum("mkk->mk", cov))
