"""``hexcal import``: a lab's own log → measurements.csv, by a mapping file of its columns."""

from __future__ import annotations

import argparse
from pathlib import Path

#: The command's name on the command line.
NAME = "import"


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``import`` command and its options."""
    ip = sub.add_parser(
        NAME, help="a lab's own log → measurements.csv, by a mapping file of its columns"
    )
    ip.add_argument("log", type=Path, help="the log, CSV with a header row")
    ip.add_argument(
        "--map",
        type=Path,
        required=True,
        help="TOML naming the log's columns, units and conventions (docs/formats.md)",
    )
    ip.add_argument("--out", type=Path, required=True, help="measurements.csv to write")
    ip.add_argument("--force", action="store_true", help="replace an existing --out file")
    ip.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from hexcal.app.commands.common import check_outputs
    from hexcal.io.log_import import import_log
    from hexcal.io.measurements import write_measurements
    from hexcal.vocabulary import counted

    out = Path(args.out)
    check_outputs((out, "measurements.csv"))
    if out.resolve() in (Path(args.log).resolve(), Path(args.map).resolve()):
        raise ValueError(f"{out}: this is an input; write the table to another file")
    if out.exists() and not args.force:
        raise ValueError(f"{out}: the file exists; pass --force to replace it")
    meas = import_log(args.log, args.map)
    write_measurements(meas, out)
    print(f"{counted(len(meas), 'pose')} from {args.log} written to {out} (mapping {args.map})")
    return 0
