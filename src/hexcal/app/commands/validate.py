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
    if args.rehome:
        from hexcal.estimate.model_validation import estimated_noise, rehome

        sig_r = sig if sig is not None else estimated_noise(model, inp.meas)[0]
        moved, shift = rehome(model, inp.meas, sig_r)
        v.rehomed = validate_model(moved, f"{v.model} re-homed", inp.meas, sig_r, source)
        v.offset_shift_mm = shift
    figures = _metrology(loaded, model, v.model, inp.meas, v.noise)
    if args.json:
        out = v.to_dict()
        u = figures.uncertainty
        out["position_coverage_95"] = (
            None if u is None else u.to_dict(False)["position_coverage_95"]
        )
        out["metrology"] = figures.to_dict()
        print(json_out.dumps(out, why=json_out.accuracy_reason, indent=2))
    else:
        from hexcal.app.plain import opening, validation_summary

        print(opening(validation_summary(v)))
        print(v.text(inp.label))
        print()
        print("\n".join(figures.lines()))
    return 0


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
