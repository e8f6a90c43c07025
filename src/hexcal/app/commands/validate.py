"""``hexcal validate``: a model on poses it was not fitted on, with its metrology figures (the
poses' expanded uncertainty and its coverage, ISO 9283, ISO 230-2); on the poses it was fitted
on, it says so first."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hexcal.app.commands.common import add_effects_option, load_effects

#: The command's name on the command line.
NAME = "validate"


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``validate`` command and its options."""
    v = sub.add_parser(
        NAME,
        help="a model on poses it was not fitted on: leg-length residual, pose error, verdict",
    )
    v.add_argument(
        "model", type=Path, help="calibrated.json, or a plain robot.json (e.g. the drawing)"
    )
    v.add_argument(
        "measurements", type=Path, help="measurements.csv or a session file of other poses"
    )
    v.add_argument(
        "--instruments",
        type=Path,
        help="instruments.json: the noise of these poses (default: a session file's own, else "
        "the model's, else estimated from the poses and said so)",
    )
    v.add_argument("--json", action="store_true", help="print one JSON object")
    v.add_argument(
        "--rehome",
        action="store_true",
        help="also re-estimate the six offsets alone on these poses (after the encoders were "
        "homed again) and report that beside the plain figure",
    )
    v.add_argument(
        "--fold-in",
        type=Path,
        metavar="OUT.json",
        help="write the model with a between-session uncertainty term from these poses (their "
        "leg residual above the fit's held-out one; re-homed with --rehome) to OUT.json (may be "
        "the model file itself): its k = 2 statement then covers another session",
    )
    v.add_argument("--force", action="store_true", help="--fold-in may replace an existing file")
    add_effects_option(v)
    v.set_defaults(func=run, robot=None)


def run(args: argparse.Namespace) -> int:
    from hexcal.app.workflow import read_inputs
    from hexcal.estimate.model_file import CalibratedRobot, leg_model_of, load_model, model_label
    from hexcal.estimate.model_validation import validate_model
    from hexcal.io import json_out

    load_effects(args)
    loaded = load_model(args.model)
    model = leg_model_of(loaded)
    if isinstance(loaded, CalibratedRobot):
        for note in loaded.source_notes(str(args.model)):
            print(f"hexcal: {note}", file=sys.stderr)
    # The robot of the table is the model's own (a session file's design is not used).
    inp = read_inputs(args.measurements, args.model, args.instruments)
    sig, source = inp.sigmas, inp.noise_source
    if args.instruments is None and isinstance(loaded, CalibratedRobot):
        from hexcal.procedure import looks_like_session

        noise = loaded.calibration.noise
        if noise is not None and not looks_like_session(args.measurements):
            from hexcal.model.noise import NoiseSigmas

            sig = NoiseSigmas.from_instruments(noise)
            source = f"the model's own ({args.model}: {loaded.calibration.noise_source})"
    v = validate_model(model, model_label(loaded), inp.meas, sig, source)
    v.own_session = _own_session(loaded, args.measurements, inp.meas)
    figures_r = None
    if args.rehome:
        from hexcal.diagnosis.metrology import of_model_file
        from hexcal.estimate.model_validation import estimated_noise, rehome

        sig_r = sig if sig is not None else estimated_noise(model, inp.meas)[0]
        moved, shift = rehome(model, inp.meas, sig_r)
        v.rehomed = validate_model(moved, f"{v.model} re-homed", inp.meas, sig_r, source)
        v.offset_shift_mm = shift
        figures_r = of_model_file(loaded, inp.meas, sig_r, v.rehomed.model, leg_model=moved)
    figures = _metrology(loaded, model, v.model, inp.meas, v.noise)
    missing = _missing(v, figures, figures_r)
    folded = None
    if args.fold_in is not None:
        folded = _fold_in(args, loaded, v, inp)
    if args.json:
        out = v.to_dict()
        u = figures.uncertainty
        out["position_coverage_95"] = (
            None if u is None else u.to_dict(False)["position_coverage_95"]
        )
        out["metrology"] = figures.to_dict()
        if figures_r is not None:
            out["rehomed"] = (out["rehomed"] or {}) | {"metrology": figures_r.to_dict()}
            ur = figures_r.uncertainty
            out["rehomed"]["position_coverage_95"] = None if ur is None else ur.coverage_95
        out["coverage_missing"] = missing
        out["folded_in"] = folded
        print(json_out.dumps(out, why=json_out.accuracy_reason, indent=2))
    else:
        from hexcal.app.plain import opening, validation_summary

        print(opening(validation_summary(v)))
        print(v.text(inp.label))
        print()
        print("\n".join(figures.lines()))
        if figures_r is not None:
            print("\n".join(figures_r.lines()[:1] + _uncertainty_lines(figures_r)))
        print("\n".join(f"coverage: {line}" for line in missing))
        if folded is not None:
            print(folded["text"])
    return 0


def _uncertainty_lines(figures) -> list[str]:
    u = figures.uncertainty
    return [] if u is None else ["  " + line for line in u.lines()]


def _missing(v, figures, figures_r) -> list[str]:
    """What the stated uncertainty lacks here (nothing on the model's own poses: a fit covers
    the data it came from)."""
    from hexcal.diagnosis.metrology import missing_terms

    return [] if v.own_session else missing_terms(v, figures, figures_r)


def _fold_in(args: argparse.Namespace, loaded, v, inp) -> dict:
    """Write the model with the between-session term these poses give (see the option)."""
    from hexcal.estimate.model_file import CalibratedRobot, save_model, sha256_of

    out: Path = args.fold_in
    if not isinstance(loaded, CalibratedRobot):
        raise ValueError(f"{args.model}: --fold-in needs a calibrated.json, not a robot.json")
    if v.own_session:
        raise ValueError(
            f"{args.measurements}: --fold-in needs poses the model was not fitted on "
            f"({v.own_session}); a between-session term from its own session would be zero"
        )
    if out.resolve() == Path(args.measurements).resolve():
        raise ValueError(f"{out}: this is the measurements input; write the model elsewhere")
    if out.exists() and not args.force and out.resolve() != Path(args.model).resolve():
        raise ValueError(f"{out}: the file exists; pass --force to replace it")
    used = v.rehomed if v.rehomed is not None else v
    how = ", re-homed" if v.rehomed is not None else ""
    source = (
        f"{Path(args.measurements).name} (SHA-256 {sha256_of(args.measurements)[:16]}…, "
        f"{used.poses} poses{how})"
    )
    try:
        folded = loaded.with_between_session(used.leg_rms_mm, used.poses, source)
    except ValueError as exc:
        raise ValueError(f"{args.model}: {exc}") from None
    save_model(folded, out)
    u = folded.calibration.uncertainty
    assert u is not None and u.between_session_mm is not None and u.heldout_rms_mm is not None
    text = (
        f"folded in: a between-session term of {1000 * u.between_session_mm:.0f} µm per leg "
        f"(these poses' leg RMS {1000 * used.leg_rms_mm:.0f} µm{how} against the fit's held-out "
        f"{1000 * u.heldout_rms_mm:.0f} µm) written to {out}; judge it on a third session, not "
        "on this one"
    )
    return {"between_session_mm": u.between_session_mm, "file": str(out), "text": text}


def _own_session(loaded, path: Path, meas) -> str | None:
    """Why the table was among the model's inputs (None: it was not, or the model is a plain
    robot.json, which was fitted on nothing)."""
    from hexcal.estimate.model_file import CalibratedRobot, sha256_of
    from hexcal.estimate.model_validation import own_session

    if not isinstance(loaded, CalibratedRobot):
        return None
    inputs = [(i.role, i.sha256) for i in loaded.calibration.provenance.inputs]
    return own_session(inputs, loaded.fitted_rows(meas), sha256_of(path))


def _metrology(loaded, model, label: str, meas, sig):
    """The metrology figures of the model on the table (the poses' uncertainty from the
    model's covariance when the file has one)."""
    from hexcal.diagnosis.metrology import of_model_file

    return of_model_file(loaded, meas, sig, label)
