"""The calibration workflow, one layer under the command line, the demo and the text UI.

session or files → noise → calibrate → diagnose → add an effect → store → export. Every front
end calls these functions and only formats what they return; nothing here prints or draws.

- :func:`read_inputs` / :func:`session_inputs`: the measurement table, the design robot, the
  noise (stated, from the session's recorded still windows, or to be estimated) and the input
  files (for provenance). A calibrated.json given as the robot brings its effects along.
- :func:`calibrate_model`: the calibration with its effects (clamp rows included), its pose
  accuracy on held-out poses beside the drawing's, and the calibrated model file.
- :func:`diagnose_chain`: the diagnosis, and with ``auto`` the named effect added until nothing
  identifiable is missing; :func:`model_of` turns any step into a calibrated model.
- :func:`store`: the model (geometry and effects) of a calibration or diagnosis step into the
  session file; :func:`export` writes the session's latest model as calibrated.json.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property, partial
from pathlib import Path
from typing import Any

import numpy as np

from hexcal.errors import MismatchError, RefusedError
from hexcal.estimate.accuracy import PoseAccuracy
from hexcal.estimate.calibrate import Calibration, calibrate
from hexcal.estimate.model_file import (
    CalibratedRobot,
    CalibrationBlock,
    FingerprintRecord,
    FitRecord,
    FittedPoses,
    Provenance,
    UncertaintyRecord,
    covariance_record,
    effect_records,
    format_version_of,
    input_records,
    load_model,
    save_model,
)
from hexcal.estimate.refine import FitStalled
from hexcal.estimate.sanity import DRAWING_TOLERANCE
from hexcal.estimate.solvers.whole_robot import Form
from hexcal.estimate.uncertainty import excess_mm
from hexcal.io.measurements import Measurements
from hexcal.io.measurements_csv import read_measurements
from hexcal.model.instruments import EncoderNoise, Instruments, TrackerNoise, load_instruments
from hexcal.model.noise import DEFAULT_SIGMAS, NoiseSigmas
from hexcal.model.robot import GeometryOutOfRange, Robot
from hexcal.vocabulary import ModelKind, counted, names_an_addition

#: The most effects ``diagnose --auto`` adds before it stops.
MAX_AUTO_STEPS = 8


@dataclass
class Inputs:
    """What a calibration reads: the table ``meas``, the ``design`` robot, the ``instruments``'
    noise (None: estimated from the residual), where the noise came from, a label for reports,
    the input files by role (for provenance and so that no output overwrites one), and the
    effects of a calibrated model given as the robot (its model, to start from)."""

    meas: Measurements
    design: Robot
    instruments: Instruments | None
    noise_source: str
    label: str
    files: dict[str, Path] = field(default_factory=dict)
    model_effects: tuple[str, ...] = ()
    #: What reading did that the user must hear (poses set aside on load, …)
    notices: list[str] = field(default_factory=list)
    #: Whether findings that rest on the drawing refuse (False: they are only reported), and
    #: the drawing check's tolerance (a fraction of the design radius)
    drawing_check: bool = True
    drawing_tolerance: float = DRAWING_TOLERANCE
    #: The data's consistency, once checked (:func:`screen_inputs`), and what it reported
    #: without refusing
    consistency: Any = field(default=None, repr=False)
    warnings: list[str] = field(default_factory=list)
    #: The legs whose encoder rebooted while recording, with the first pose after: (leg, pose id)
    reboots: tuple[tuple[int, int], ...] = ()

    @property
    def sigmas(self) -> NoiseSigmas | None:
        return None if self.instruments is None else NoiseSigmas.from_instruments(self.instruments)

    def without(self, pose_ids: Sequence[int]) -> Inputs:
        """The same inputs with the poses ``pose_ids`` left out (an unknown id is refused)."""
        ids = {int(i) for i in pose_ids}
        known = set(self.meas.pose_id.tolist())
        unknown = sorted(ids - known)
        if unknown:
            raise ValueError(
                f"{self.label}: no pose with id {', '.join(map(str, unknown))} to exclude"
            )
        keep = ~np.isin(self.meas.pose_id, sorted(ids))
        meas = self.meas.subset(keep)
        label = (
            f"{self.label.rsplit(' (', 1)[0]} ({counted(len(meas), 'pose')}; {len(ids)} excluded)"
        )
        return replace(self, meas=meas, label=label, consistency=None)


class FitFailed(RefusedError, ValueError):
    """The refinement did not converge: the message names the poses pulling it."""


class FitDiverged(RefusedError, ValueError):
    """The fit diverged (its geometry left every plausible value): the message says so, with
    the likely causes ranked from the data's own signature; never a fault of the user's files."""


class DataMismatch(MismatchError):
    """The data disagree with themselves or with the drawing, found before any fit (a unit, a
    sign, the quaternion order, swapped legs, an offset): exit status 4."""


def pose_names(meas: Measurements, rows: Iterable[int]) -> str:
    """'pose 40 (step leg2-length, t 536.3 s), …' for 0-based rows."""
    return ", ".join(
        f"pose {int(meas.pose_id[i])} (step {meas.step[i]}, t {float(meas.t[i]):g} s)" for i in rows
    )


def screen_outliers(inp: Inputs) -> None:
    """Refuse gross outlier poses before any fit (:func:`hexcal.estimate.sanity.gross_outliers`): a typo
    or a pose taken mid-move would otherwise pull the geometry off by metres."""
    from hexcal.estimate.sanity import gross_outliers, outlier_message

    found = gross_outliers(inp.meas, inp.design)
    if found:
        raise ValueError(outlier_message(found, inp.label))


def consistency_of(inp: Inputs) -> Any:
    """The data's consistency (:func:`hexcal.estimate.consistency.check_consistency`), checked
    once per inputs; in a session whose encoder rebooted, on the poses before the first reboot
    when they are enough to judge, else on all of them less the findings of the rebooted legs
    alone (the diagnosis tests the zero step at the reboot)."""
    from hexcal.estimate.consistency import MIN_POSES as CONSISTENCY_MIN_POSES
    from hexcal.estimate.consistency import check_consistency

    if inp.consistency is None:
        meas, whole = inp.meas, True
        if inp.reboots:  # a lost zero breaks the linear check: judged on the poses before it
            before = meas.pose_id < min(pose_id for _, pose_id in inp.reboots)
            if before.sum() >= CONSISTENCY_MIN_POSES:
                meas, whole = meas.subset(before), False
        c = check_consistency(meas, inp.design, inp.drawing_tolerance, inp.label.rsplit(" (", 1)[0])
        if inp.reboots and whole:  # too few before: a rebooted leg's findings are the step's
            rebooted = {leg for leg, _ in inp.reboots}
            c.findings = [f for f in c.findings if not f.legs or not set(f.legs) <= rebooted]
        inp.consistency = c
    return inp.consistency


def screen_inputs(inp: Inputs) -> list[str]:
    """The cheap checks, before any fit: the data's own consistency (units, signs, quaternion
    order, and against the drawing its size, its legs and offsets), then gross outlier poses.
    Raises :class:`DataMismatch` (or the outliers' refusal); returns what is reported without
    refusing (findings that rest on the drawing when :attr:`Inputs.drawing_check` is off).
    Readings beyond the stroke (``leg_range_mm``) are refused first: no other finding holds
    on readings no leg can give."""
    screen_stroke(inp)
    c = consistency_of(inp)
    refused = c.refusals(inp.drawing_check)
    if refused:
        lines = "\n".join(f"  {f.text}" for f in refused)
        hint = (
            "; if the drawing itself is wrong, --drawing-tolerance or --no-drawing-check"
            if any(f.drawing for f in refused)
            else ""
        )
        raise DataMismatch(
            f"the data do not agree with {'the drawing' if all(f.drawing for f in refused) else 'themselves'}"
            f"; nothing was fitted:\n{lines}\nfix the cause and calibrate again{hint}"
        )
    screen_outliers(inp)
    return [f.text for f in c.warnings(inp.drawing_check)]


def screen_stroke(inp: Inputs) -> None:
    """Refuse readings beyond robot.json's ``leg_range_mm`` by more than the reading noise
    (:func:`hexcal.diagnosis.limits.beyond_stroke`): :class:`DataMismatch` naming the legs,
    how far and the likely cause."""
    from hexcal.diagnosis.limits import beyond_stroke, stroke_message

    sigma = None if inp.instruments is None else inp.instruments.sigma_reading_mm
    found = beyond_stroke(inp.meas, inp.design, sigma)
    if found:
        raise DataMismatch(
            stroke_message(inp.meas, inp.design, found, inp.label.rsplit(" (", 1)[0])
        )


def _causes(inp: Inputs) -> str:
    from hexcal.estimate.consistency import likely_causes

    causes = likely_causes(inp.meas, inp.design, inp.drawing_tolerance)
    return "".join(f"\n  {i}. {c}" for i, c in enumerate(causes, 1))


def _stall_message(inp: Inputs, exc: Exception) -> RefusedError:
    """The refusal of a fit that did not converge (:class:`FitFailed`) or diverged
    (:class:`FitDiverged`), with the likely causes from the data's own signature."""
    causes = _causes(inp)
    if isinstance(exc, (GeometryOutOfRange, FitDiverged)):
        what = str(exc).split("\n", 1)[0].removeprefix("computed geometry: ")
        return FitDiverged(
            f"{inp.label}: the fit diverged ({what}): its geometry left every plausible value, "
            "so the model and the data disagree somewhere; this is not an error in the robot "
            "file. "
            + (
                f"The likely causes, from the data's own signature, most likely first:{causes}"
                if causes
                else "No cause stands out in the data's signature: check the table's columns, "
                "units and signs, and the robot description"
            )
        )
    rows = getattr(exc, "rows", [])
    pulling = f"; the poses pulling it: {pose_names(inp.meas, rows)}" if rows else ""
    likely = f"\nthe data's own signature suggests, most likely first:{causes}" if causes else ""
    return FitFailed(
        f"{inp.label}: the calibration did not converge ({exc}){pulling}. Check those poses "
        "(a typo, a pose taken mid-move, a swapped column), leave them out with "
        f"--exclude-poses, or check the robot description{likely}"
    )


def check_diverged(inp: Inputs, robot: Robot) -> None:
    """Refuse a fitted geometry that left every plausible value (:class:`FitDiverged`)."""
    from hexcal.estimate.sanity import divergence

    why = divergence(robot.a, robot.b, robot.offsets, inp.design)
    if why is not None:
        raise _stall_message(inp, FitDiverged(why))


def check_drawing(inp: Inputs, cal: Calibration, tolerance: float | None = None) -> list[str]:
    """The calibration against the drawing (:func:`hexcal.estimate.sanity.check_against_drawing`): one
    line per leg that does not match, with the poses that pull it most; empty when it does."""
    from hexcal.estimate.consistency import offset_findings
    from hexcal.estimate.sanity import check_against_drawing

    tol = DRAWING_TOLERANCE if tolerance is None else tolerance
    found = check_against_drawing(cal.robot.a, cal.robot.b, inp.design, tol)
    lines = []
    for f in found:
        worst = np.argsort(-np.abs(cal.residuals[:, f.legs[0] - 1]))[:3]
        lines.append(
            f"{f.text}; the poses that pull leg {f.legs[0]} most: {pose_names(inp.meas, worst)}"
        )
    if not found and cal.model == ModelKind.M42 and "leg_offsets" in inp.design.model_fields_set:
        lines += [
            f.text.removeprefix("fitted: ")
            for f in offset_findings(cal.robot.offsets, inp.design, tol, "fitted")
        ]
    return lines


def read_inputs(
    measurements: Path, robot: Path | None = None, instruments: Path | None = None
) -> Inputs:
    """Inputs from a measurements.csv (needs ``robot``) or a session file (carries its own
    robot and, once recorded, its noise); ``robot`` may be a calibrated.json, whose effects
    become :attr:`Inputs.model_effects`."""
    from hexcal.procedure import looks_like_session

    files: dict[str, Path] = {"measurements": Path(measurements)}
    effects: tuple[str, ...] = ()
    design: Robot | None = None
    notices: list[str] = []
    if robot is not None:
        files["robot"] = Path(robot)
        loaded = load_model(robot)
        if isinstance(loaded, CalibratedRobot):
            effects = tuple(e.name for e in loaded.calibration.effects)
            design = loaded.plain_robot()
            notices += loaded.source_notes(str(robot))
        else:
            design = loaded
    inst, source = None, "estimated from the residual"
    if instruments is not None:
        files["instruments"] = Path(instruments)
        inst, source = load_instruments(instruments), f"stated in {instruments}"
    if looks_like_session(measurements):
        from hexcal.procedure.session import load_session

        session = load_session(measurements, notices)
        meas = session.measurements()
        design = design or session.robot
        reboots = tuple((r.leg, r.pose_id) for r in session.encoder_reboots)
        if inst is None and session.instruments is not None:
            inst = session.instruments
            how = getattr(session.instruments, "source", None) or "the session's noise"
            source = f"from {measurements}: {how}"
    else:
        if design is None:
            raise ValueError(
                f"{measurements}: a measurement table needs the robot description: pass "
                "--robot robot.json (a session file carries its own)"
            )
        meas = read_measurements(measurements, notices)
    label = f"{measurements} ({counted(len(meas), 'pose')})"
    inp = Inputs(meas, design, inst, source, label, files, effects, notices)
    if looks_like_session(measurements):
        inp.reboots = reboots
    return inp


def session_instruments(session: Any) -> Instruments | None:
    """The noise of a recorded session's poses, from the scatter in their still windows
    (None when the poses carry no raw samples, e.g. an imported table)."""
    from hexcal.procedure.guided import pose_from_record
    from hexcal.procedure.recording import window_instruments

    return window_instruments([pose_from_record(r) for r in session.poses])


def session_inputs(session: Any, path: Path | str) -> Inputs:
    """Inputs of a session being recorded (the text UI, the demo): its table, its design and
    the noise of its own still windows."""
    meas = session.measurements()
    inst = session_instruments(session)
    if inst is None:
        source = "estimated from the residual"
    else:
        source = inst.stated_source() or "estimated from the still windows of the recorded poses"
    return Inputs(
        meas,
        session.robot,
        inst,
        source,
        f"{path} ({counted(len(meas), 'pose')})",
        {"session": Path(path)},
    )


def procedure_steps(proc: Any, poses_per_step: int | None, free_poses: int | None) -> list:
    """The procedure's steps with the operator's pose counts: ``poses_per_step`` for clamped
    steps, ``free_poses`` for free ones (None: the procedure's recommended counts), never below
    a step's minimum; steps at home keep theirs. Counts that add up to more than a session holds
    are refused (:func:`hexcal.procedure.steps.check_total`)."""

    def count(s: Any) -> int:
        if s.at_home:
            return int(s.n_poses)
        n = free_poses if s.leg == 0 else poses_per_step
        return max(int(n), int(s.min_poses)) if n else int(s.n_poses)

    from hexcal.procedure.steps import check_total

    steps = [replace(s, n_poses=count(s)) for s in proc.expand()]
    check_total([s.n_poses for s in steps], f"procedure {proc.name!r}", "these pose counts ask for")
    return steps


# -- calibration ------------------------------------------------------------------------------
@dataclass
class ModelResult:
    """A calibrated model: the ``calibration`` (clamp rows included), its pose ``accuracy``
    (the drawing on every pose, then each model on held-out poses, the last one this model's),
    and the calibrated model :attr:`file`, made by ``make_file`` when first asked for (a
    calibration that writes no file does not validate one: 15 ms of ``hexcal calibrate``)."""

    calibration: Calibration
    accuracy: list[PoseAccuracy]
    make_file: Callable[[], CalibratedRobot] = field(repr=False)
    #: How the calibration does not match the drawing, one line per leg (then ``accuracy`` is
    #: empty: a model about to be refused is not measured)
    mismatch: list[str] = field(default_factory=list)

    @cached_property
    def file(self) -> CalibratedRobot:
        """The calibrated model file (robot.json's keys and the calibration block)."""
        return self.make_file()

    @property
    def name(self) -> str:
        return self.calibration.model_name


def floor_sigmas(inp: Inputs, chi2_per_dof: float) -> NoiseSigmas:
    """The noise that sets the pose-error floor: the stated one, or the typical tracker and
    encoder scaled to the fit's residual."""
    if inp.sigmas is not None:
        return inp.sigmas
    s = float(np.sqrt(max(chi2_per_dof, 0.0)))
    d = DEFAULT_SIGMAS
    return NoiseSigmas(s * d.position_mm, s * d.orientation_rad, s * d.reading_mm)


def _noise_record(inp: Inputs, cal: Calibration) -> tuple[Instruments | None, str]:
    if inp.instruments is not None:
        return inp.instruments, inp.noise_source
    r = cal.refinement
    if r is None:
        return None, "not known (linear methods only)"
    sig = floor_sigmas(inp, r.chi2 / r.dof)
    if not (sig.position_mm <= 1000.0 and np.degrees(sig.orientation_rad) <= 180.0):
        return None, "estimated from the residual, beyond any instrument's noise: not recorded"
    source = "estimated from the residual (a typical tracker and encoder, scaled to χ²/dof)"
    inst = Instruments(
        tracker=TrackerNoise(
            position_sigma_mm=sig.position_mm,
            orientation_sigma_deg=float(np.degrees(sig.orientation_rad)),
        ),
        encoders=EncoderNoise(reading_sigma_mm=sig.reading_mm),
        source=source,
    )
    return inst, source


def build_file(
    inp: Inputs,
    cal: Calibration,
    accuracy: list[PoseAccuracy],
    heldout_rms_mm: float | None,
    noise_floor_mm: float | None,
) -> CalibratedRobot:
    """The calibrated model file of a calibration (see :mod:`hexcal.estimate.model_file`)."""
    r = cal.refinement
    model = cal.leg_model()
    noise, source = _noise_record(inp, cal)
    name = cal.model_name
    if cal.session_effects:
        shipped = f"Model {cal.model}" + model.name
        name = f"{shipped} (fitted with {', '.join(cal.session_effects)}: the session's, left out)"
    effects = effect_records(model, cal.sigmas())
    cov = None
    if r is not None:
        cov = covariance_record(r.names, r.cov, r.sigma, model, cal.model == ModelKind.M42)
    block = CalibrationBlock(
        format_version=format_version_of(
            effects, covariance=r is not None, fitted_poses=True, fingerprint=True
        ),
        model=name,
        kind=cal.model,
        effects=effects,
        noise=noise,
        noise_source=source,
        fit=FitRecord(
            poses=len(inp.meas),
            chi2_per_dof=None if r is None else float(r.chi2 / r.dof),
            rms_mm=cal.rms_mm,
            heldout_rms_mm=heldout_rms_mm,
            noise_floor_mm=noise_floor_mm,
            clamps=None if cal.clamp_check is None else cal.clamp_check.text,
        ),
        accuracy=[_record(a) for a in accuracy],
        provenance=Provenance(poses=len(inp.meas), inputs=input_records(dict(inp.files))),
        covariance=cov,
        fitted_poses=FittedPoses(
            pose_id=[int(i) for i in inp.meas.pose_id],
            t=[float(t) for t in inp.meas.t],
            fingerprint=FingerprintRecord.of(inp.meas),
        ),
        uncertainty=_uncertainty_record(inp, cal, noise, heldout_rms_mm, cov),
    )
    data = cal.robot.model_dump(exclude_none=True)
    data.pop("calibration", None)
    data["name"] = f"{inp.design.name}-calibrated"
    data["calibration"] = block
    return CalibratedRobot.model_validate(data)


def _uncertainty_record(
    inp: Inputs,
    cal: Calibration,
    noise: Instruments | None,
    heldout_rms_mm: float | None,
    cov: Any = None,
) -> UncertaintyRecord | None:
    """The model-inadequacy term of a calibration: its held-out leg RMS above what the recorded
    noise and the parameters' covariance ``cov`` (already in the statement) give on its poses;
    an estimated noise floor no higher than that residual, as the diagnosis caps it. None
    without a held-out residual or a noise."""
    from hexcal.estimate.effect_fit import K_FOLDS
    from hexcal.estimate.model_validation import EXCESS_Z
    from hexcal.estimate.uncertainty import parameter_leg_rms_mm
    from hexcal.model.noise import leg_covariance

    if heldout_rms_mm is None or noise is None or not np.isfinite(heldout_rms_mm):
        return None
    sig = NoiseSigmas.from_instruments(noise)
    m = inp.meas
    legs = leg_covariance(cal.robot.a, cal.robot.b, m.position, m.rotations.as_matrix(), sig)
    floor = float(np.sqrt(np.mean(np.einsum("mkk->mk", legs))))
    if inp.instruments is None:
        floor = min(floor, heldout_rms_mm)
    params = 0.0
    if cov is not None:
        params = parameter_leg_rms_mm(cal.leg_model(), cov.parameters, np.array(cov.matrix), m)
    # A held-out residual comes from fits on (K − 1)/K of the poses: their parameters' share
    # is K/(K − 1) times the whole fit's.
    stated = float(np.hypot(floor, params * np.sqrt(K_FOLDS / (K_FOLDS - 1))))
    # Only an excess beyond the held-out RMS's own scatter (the validation's band, 4σ of χ²
    # over the 6M residuals) is the model's: below it, h exceeds what is stated by chance.
    band = 1.0 + EXCESS_Z * float(np.sqrt(2.0 / (6 * len(m))))
    inadequacy = excess_mm(heldout_rms_mm, stated) if heldout_rms_mm**2 > band * stated**2 else 0.0
    return UncertaintyRecord(
        heldout_rms_mm=heldout_rms_mm,
        floor_mm=floor,
        parameters_mm=params,
        model_inadequacy_mm=inadequacy,
    )


def _record(a: PoseAccuracy):
    from hexcal.estimate.model_file import AccuracyRecord

    d = a.to_dict()
    d["floor_estimated"] = d["floor_estimated"] or None  # written only when true
    return AccuracyRecord.model_validate(
        {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in d.items()}
    )


def calibrate_model(
    inp: Inputs,
    model: ModelKind = ModelKind.M42,
    effects: Sequence[str] = (),
    clamps: bool = True,
    form: Form = "paper",
    do_refine: bool = True,
    on_stage: Callable[[str], None] | None = None,
    drawing_tolerance: float | None = None,
) -> ModelResult:
    """Calibrate Model ``model`` with ``effects`` (and the model file's own, when the robot
    given was a calibrated.json), then measure its pose accuracy on held-out poses against the
    drawing's and, with effects, the geometry alone. ``on_stage`` is told each stage as it
    starts (a progress display).

    The cheap checks come first (:func:`screen_inputs`: the data's consistency, outliers); a
    fit that diverges is refused as such (:class:`FitDiverged`). With ``drawing_tolerance``
    the calibration is checked against the drawing (:func:`check_drawing`) before the pose
    accuracy: a mismatch is returned in :attr:`ModelResult.mismatch`, unmeasured."""
    from hexcal.estimate.effect_fit import (
        Problem,
        design_accuracy,
        fit_model,
        heldout_accuracy,
        noise_floor,
    )

    effects = tuple(dict.fromkeys((*inp.model_effects, *effects)))
    stage = on_stage or (lambda text: None)
    screen_inputs(inp)
    inp = locate_effects_of(inp, model, effects)
    stage(f"calibrating Model {int(model)} on {len(inp.meas.pose_id)} poses")
    try:
        cal = calibrate(
            inp.meas,
            inp.design,
            model=model,
            instruments=inp.instruments,
            form=form,
            do_refine=do_refine,
            effects=effects,
            clamps=clamps,
        )
    except (FitStalled, GeometryOutOfRange) as exc:
        raise _stall_message(inp, exc) from None
    check_diverged(inp, cal.robot)
    if drawing_tolerance is not None:
        mismatch = check_drawing(inp, cal, drawing_tolerance)
        if mismatch:
            return ModelResult(cal, [], partial(build_file, inp, cal, [], None, None), mismatch)
    stage("the pose accuracy on held-out poses (5 folds)")
    # The calibration's own linear seed is the problem's when it is Model 42's by the paper's
    # forms (the same arrays, the same solver): not made again.
    seed = cal.linear if model == ModelKind.M42 and form == "paper" and not cal.effects else None
    problem = Problem.build(inp.meas, inp.design, inp.sigmas, seed)
    base = ("offset",) if model == ModelKind.M42 else ()
    chain = [base] if not cal.effects else [base, (*base, *cal.effects)]
    # The calibration's own fit from the leg lengths is the first model's: not made again
    # (the same seed, when the seed is the paper's forms).
    made = cal.lengths_fit if form == "paper" else None
    try:
        fits = [fit_model(problem, c, refinement=made if c == base else None) for c in chain]
    except (FitStalled, GeometryOutOfRange) as exc:
        raise _stall_message(inp, exc) from None
    r = cal.refinement
    sig = floor_sigmas(inp, fits[-1].chi2 / fits[-1].dof if r is None else r.chi2 / r.dof)
    # Without stated noise the only level is the fit's own residual: a floor from it would put
    # every model at its floor by construction, so none is shown.
    floor_sig = sig if inp.sigmas is not None else None
    accuracy = [design_accuracy(problem, floor_sig)] + [
        heldout_accuracy(problem, f, floor_sig) for f in fits
    ]
    floor = None
    if inp.sigmas is not None:
        floor = float(np.sqrt(np.mean(noise_floor(problem, fits[-1]) ** 2)))
    return ModelResult(
        cal, accuracy, partial(build_file, inp, cal, accuracy, fits[-1].cv_rms_mm, floor)
    )


def locate_effects_of(inp: Inputs, model: ModelKind, effects: Sequence[str]) -> Inputs:
    """The inputs with the places of the searched-for effects among ``effects`` located by the
    diagnosis' own search (:func:`hexcal.diagnosis.locators.locate_effects`: zero_step's
    times), unless robot.json states them; refused with the effect's reason when the search
    finds none."""
    from hexcal.diagnosis.locators import LOCATORS, locate_effects
    from hexcal.estimate.effect_fit import Problem

    if not any(e in LOCATORS for e in effects):
        return inp
    problem = Problem.build(inp.meas, inp.design, inp.sigmas)
    base = ("offset",) if model == ModelKind.M42 else ()
    try:
        locate_effects(problem, (*base, *effects))
    except (FitStalled, GeometryOutOfRange) as exc:
        raise _stall_message(inp, exc) from None
    return replace(inp, design=problem.design)


# -- diagnosis --------------------------------------------------------------------------------
def diagnose_chain(
    inp: Inputs,
    model: ModelKind = ModelKind.M42,
    add: Sequence[str] = (),
    auto: bool = False,
    on_step: Callable[[Any], None] | None = None,
    previous: Any = None,
    explore_dir: Path | None = None,
) -> list:
    """Diagnose Model ``model`` + ``add`` (and the model file's effects); with ``auto``, add
    the named effect and diagnose again until the verdict is ``none`` or ``unexplained`` (at
    most :data:`MAX_AUTO_STEPS`). With ``explore_dir`` too, an ``unexplained`` verdict whose
    residual the explorer can point at goes on as well: the lead is written there as an effect
    file (:func:`hexcal.diagnosis.effect_file.write_explored`), loaded, added, and the chain
    diagnoses again — until the residual is at the floor or nothing significant is left. ``previous``: an earlier diagnosis
    of the same inputs, whose precomputed problem is reused. ``on_step`` is called with each
    diagnosis as it is done."""
    from hexcal.diagnosis import diagnose
    from hexcal.diagnosis.effect_file import write_explored
    from hexcal.diagnosis.same_poses import compare_steps

    added = list(dict.fromkeys((*inp.model_effects, *add)))
    problem = None if previous is None else previous.problem
    if previous is None:
        screen_inputs(inp)
    steps: list[Any] = []
    while True:
        try:
            d = diagnose(
                inp.meas,
                inp.design,
                model,
                add=list(added),
                instruments=inp.instruments,
                problem=problem,
            )
        except (FitStalled, GeometryOutOfRange) as exc:
            raise _stall_message(inp, exc) from None
        problem = d.problem
        _name_the_floor(d, inp)
        if steps:
            compare_steps(steps[-1], d)
        steps.append(d)
        if on_step is not None:
            on_step(d)
        if not auto or len(steps) >= MAX_AUTO_STEPS:
            return steps
        if names_an_addition(d.verdict):
            added.append(d.verdict)
        elif explore_dir is not None and (name := write_explored(d, explore_dir, inp.label)):
            added.append(name)
        else:
            return steps


def reboot_findings(inp: Inputs, steps: Sequence[Any]) -> list[Any]:
    """The zero step at each encoder reboot the session marked, tested on the chain's first
    model (:func:`hexcal.diagnosis.reboot.reboot_steps`); empty without reboots."""
    if not inp.reboots or not steps:
        return []
    from hexcal.diagnosis.reboot import reboot_steps

    d = steps[0]
    return reboot_steps(d.problem, d.fit, inp.reboots, d.noise_level)


def _name_the_floor(d: Any, inp: Inputs) -> None:
    """The noise floor's source in the inputs' own words when they were not stated in a file
    (a session's still windows): one name for the noise on every screen and in every report."""
    if inp.instruments is not None and not inp.noise_source.startswith("stated"):
        d.floor_source = f"{inp.noise_source}, propagated through the fitted model"


def model_of(
    inp: Inputs, chain: Sequence[Any], model: ModelKind = ModelKind.M42, clamps: bool = True
) -> ModelResult:
    """The calibrated model of a diagnosis chain's last step: calibrated with its effects
    (clamp rows included); the pose accuracy of every step, from the diagnoses' own held-out
    folds, after the drawing's."""
    last = chain[-1]
    effects = tuple(e for e in last.effects if e != "offset")
    outliers = getattr(last, "outlier_ids", [])
    if outliers:  # the diagnosis set them aside: the model is calibrated without them too
        inp = inp.without(outliers)
    from hexcal.diagnosis.locators import carry_located

    # the places the diagnosis located (the events' times), as calibrate would find them
    inp = replace(inp, design=carry_located(last.problem.design, inp.design, effects))
    try:
        cal = calibrate(
            inp.meas,
            inp.design,
            model=model,
            instruments=inp.instruments,
            effects=effects,
            clamps=clamps,
        )
    except (FitStalled, GeometryOutOfRange) as exc:
        raise _stall_message(inp, exc) from None
    check_diverged(inp, cal.robot)
    accuracy = [last.design_accuracy] + [d.accuracy for d in chain]
    floor = last.noise_floor_mm if last.problem.sigmas is not None else None
    return ModelResult(
        cal, accuracy, partial(build_file, inp, cal, accuracy, last.fit.cv_rms_mm, floor)
    )


# -- session and files ------------------------------------------------------------------------
def result_record(
    kind: str, result: ModelResult, meas: Measurements, summary: dict | None = None
) -> Any:
    """A session ``results`` entry holding the whole model (geometry and effects)."""
    from hexcal.procedure.session import ResultRecord

    cal = result.calibration
    base = {
        "model": result.name,
        "rms_mm": cal.rms_mm,
        "pose_accuracy": [_record(a).model_dump() for a in result.accuracy],
    }
    return ResultRecord(
        kind=kind,
        model=cal.model,
        effects=list(cal.effects),
        pose_ids=[int(i) for i in meas.pose_id],
        robot=cal.robot,
        calibrated=result.file,
        summary=base | (summary or {}),
    )


def store(
    sf: Any, kind: str, result: ModelResult, meas: Measurements, summary: dict | None = None
) -> None:
    """Keep a calibration or diagnosis step's model in the session file (saved at once)."""
    sf.add_result(result_record(kind, result, meas, summary))


def refuse_overwrite(out: Path, inp: Inputs, force: bool = False) -> None:
    """An output path that is one of the inputs is refused; an existing file needs ``force``."""
    out_r = Path(out).resolve()
    for role, p in inp.files.items():
        if Path(p).resolve() == out_r:
            raise ValueError(f"{out}: this is the {role} input; write the output to another file")
    if Path(out).exists() and not force:
        raise ValueError(
            f"{out}: the file exists; pass --force to replace it, or choose another name"
        )


def save_result(result: ModelResult, out: Path, inp: Inputs, force: bool = False) -> None:
    """Write the calibrated model file, never over an input (nor an existing file unless
    ``force``)."""
    refuse_overwrite(out, inp, force)
    save_model(result.file, out)


def export(session: Any, out: Path | str) -> list[str]:
    """The session as plain files (measurements.csv, robot.json and the latest model as
    calibrated.json, see :func:`hexcal.procedure.session.export_session`)."""
    from hexcal.procedure.session import export_session

    return export_session(session, out)
