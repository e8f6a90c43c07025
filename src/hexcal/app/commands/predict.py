"""``hexcal predict``: readings → poses, or poses → readings, with the model's effects."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hexcal.app.commands.common import add_effects_option, check_outputs, load_effects, number


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``predict`` command and its options."""
    pr = sub.add_parser(
        "predict",
        help="readings → poses, or poses → readings (the compensation), with the model's effects",
    )
    pr.add_argument("model", type=Path, help="calibrated.json or robot.json")
    pr.add_argument(
        "table",
        type=Path,
        help="CSV with rho1..rho6 (mm) to compute poses, or x,y,z (mm),qw,qx,qy,qz to compute "
        "readings; optional t (s), temperature (degC); rows in motion order",
    )
    pr.add_argument(
        "--to", choices=("pose", "readings"), help="what to compute (when the table has both)"
    )
    pr.add_argument(
        "--temperature",
        type=number(float, -273.15, 1000.0),
        help="structure temperature for every row, degC",
    )
    pr.add_argument("--out", type=Path, help="CSV to write (default: standard output)")
    pr.add_argument("--force", action="store_true", help="replace an existing --out file")
    add_effects_option(pr)
    pr.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from hexcal.estimate.model_file import CalibratedRobot, leg_model_of, load_model
    from hexcal.estimate.predict_table import direction, predict_table, read_table, write_table
    from hexcal.io.fileio import write_text_atomic

    check_outputs((args.out, "predicted.csv"))
    load_effects(args)
    loaded = load_model(args.model)
    if isinstance(loaded, CalibratedRobot):
        for note in loaded.source_notes(str(args.model)):
            print(f"hexcal: {note}", file=sys.stderr)
    model = leg_model_of(loaded)
    table = read_table(args.table)
    to = direction(table, args.to)
    names, values = predict_table(model, table, to, args.temperature)
    text = write_table(table, names, values)
    if args.out:
        if Path(args.out).resolve() in (Path(args.table).resolve(), Path(args.model).resolve()):
            raise ValueError(f"{args.out}: this is an input; write the output to another file")
        if Path(args.out).exists() and not args.force:
            raise ValueError(f"{args.out}: the file exists; pass --force to replace it")
        write_text_atomic(args.out, text)
        print(f"{len(values)} {'poses' if to == 'pose' else 'readings'} written to {args.out}")
    else:
        sys.stdout.write(text)
    return 0
