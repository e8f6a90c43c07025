"""``hexcal calibrate``: calibrate Model 36 or 42 from a measurement table."""

from __future__ import annotations

import argparse
from pathlib import Path

from hexcal.app.commands.common import (
    add_effects_option,
    add_model_option,
    add_pose_selection,
    check_outputs,
    drawing_tolerance,
    load_effects,
    read_inputs,
    report_mismatch,
)

#: The command's name on the command line.
NAME = "calibrate"


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``calibrate`` command and its options."""
    c = sub.add_parser(NAME, help="calibrate Model 36 or 42 from a measurement table")
    c.add_argument(
        "measurements", type=Path, help="measurements.csv (docs/formats.md) or a session file"
    )
    c.add_argument(
        "--robot",
        type=Path,
        help="robot.json: design values, known offsets (a session file carries its own)",
    )
    add_model_option(c)
    c.add_argument(
        "--instruments", type=Path, help="instruments.json: the noise that weights the fit"
    )
    c.add_argument(
        "--form",
        choices=("paper", "direct"),
        default="paper",
        help="linear seed: the paper's forms or the direct ones",
    )
    c.add_argument("--no-refine", action="store_true", help="stop after the linear methods")
    c.add_argument(
        "--lengths-only",
        action="store_true",
        help="refine from the leg lengths alone, without the clamps' own constraints",
    )
    c.add_argument(
        "--add",
        nargs="+",
        metavar="EFFECT",
        help="effects to fit with the geometry (the catalogue's, or loaded with --effects)",
    )
    add_effects_option(c)
    c.add_argument("--json", action="store_true", help="print one JSON object")
    c.add_argument(
        "--out",
        type=Path,
        help="write the calibrated model here (calibrated.json: the geometry as robot.json has "
        "it, plus every effect with its parameters; docs/formats.md)",
    )
    c.add_argument("--force", action="store_true", help="replace an existing --out file")
    c.add_argument(
        "--verbose", action="store_true", help="every statistic (the parameters' correlations)"
    )
    add_pose_selection(c)
    c.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import json

    from hexcal.app.progress import progress, wanted
    from hexcal.app.report_text import calibration_json, calibration_text
    from hexcal.app.workflow import calibrate_model, refuse_overwrite, save_result
    from hexcal.estimate.accuracy import accuracy_table
    from hexcal.io import json_out
    from hexcal.vocabulary import ModelKind

    check_outputs((args.out, "calibrated.json"))
    load_effects(args)
    inp = read_inputs(args)
    if args.out:
        refuse_overwrite(args.out, inp, args.force)
    with progress(wanted(args.json)) as bar:
        result = calibrate_model(
            inp,
            model=ModelKind(args.model),
            effects=tuple(args.add or ()),
            clamps=not args.lengths_only,
            form=args.form,
            do_refine=not args.no_refine,
            on_stage=bar.stage,
            drawing_tolerance=drawing_tolerance(args),
        )
    cal = result.calibration
    mismatch = result.mismatch  # then unmeasured: a model about to be refused
    if args.out and not mismatch:
        save_result(result, args.out, inp, args.force)
    if args.json:
        out = json.loads(calibration_json(cal, str(args.measurements), inp.noise_source))
        out["model_name"] = result.name
        out["effects"] = list(cal.effects)
        out["pose_accuracy"] = [a.to_dict() for a in result.accuracy]
        if inp.warnings:
            out["data_warnings"] = inp.warnings
        if mismatch:
            out["drawing_mismatch"] = mismatch
        print(json_out.dumps(out, why=json_out.accuracy_reason, indent=2))
    else:
        from hexcal.app.plain import calibration_summary, opening
        from hexcal.io.advice import diagnose_command, line

        next_step = line(diagnose_command(args, auto=True))
        plain = calibration_summary(result.name, result.accuracy, mismatch, next_step)
        print(opening(plain))
        print(calibration_text(cal, inp.label, _noise_line(inp, cal), verbose=args.verbose))
        if result.accuracy:
            print(
                "\npose accuracy (the pose the model computes from the readings, against the "
                "tracker):"
            )
            print(accuracy_table(result.accuracy))
        if args.out and not mismatch:
            print(f"\ncalibrated model ({result.name}) written to {args.out}")
    return report_mismatch(mismatch, args)


def _noise_line(inp, cal) -> str:
    inst = inp.instruments
    if inst is not None:
        return (
            f"{inp.noise_source}: tracker {inst.tracker.position_sigma_mm} mm, "
            f"{inst.tracker.orientation_sigma_deg} deg; encoders {inst.encoders.reading_sigma_mm} mm (1 sigma)"
        )
    line = (
        "estimated from the residual (no --instruments given: relative weights of a typical tracker "
        "and encoder, overall level from chi²/dof)"
    )
    if cal.refinement is not None:
        line += f"; the fit implies {cal.refinement.noise_scale:.2f}× those typical sigmas"
    return line
