"""``hexcal session``: export a session file, or make one from a CSV."""

from __future__ import annotations

import argparse
from pathlib import Path

from hexcal.app.commands.common import print_help_of, refuse_existing


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``session`` group: ``export``, ``import``."""
    se = sub.add_parser("session", help="export a session file, or make one from a CSV")
    se_sub = se.add_subparsers(dest="session_command", metavar="{export,import}")
    print_help_of(se)
    ex = se_sub.add_parser("export", help="measurements.csv, robot.json, calibrated.json")
    ex.add_argument("session", type=Path, help="the session file (JSON)")
    ex.add_argument("--out", type=Path, required=True, help="directory to write")
    ex.add_argument("--force", action="store_true", help="replace the files of an earlier export")
    ex.set_defaults(func=run)
    im = se_sub.add_parser("import", help="a session file from an interchange table")
    im.add_argument("measurements", type=Path, help="measurements.csv (docs/formats.md)")
    im.add_argument("--robot", type=Path, required=True, help="the robot's design, robot.json")
    im.add_argument("--out", type=Path, required=True, help="session file to create")
    im.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from hexcal.estimate.model_file import load_robot
    from hexcal.io.measurements_csv import read_measurements
    from hexcal.procedure.session import Session, SessionFile, export_session, load_session

    if args.session_command == "export":
        names = ["measurements.csv", "robot.json", "instruments.json", "calibrated.json"]
        if any((Path(args.out) / n).resolve() == Path(args.session).resolve() for n in names):
            raise ValueError(
                f"{args.session}: the export would replace the session; choose another --out"
            )
        refuse_existing(args.out, names, args.force)
        written = export_session(load_session(args.session), args.out)
        print(f"exported {args.session} to {Path(args.out)}/: {', '.join(written)}")
        return 0
    inputs = {Path(args.measurements).resolve(), Path(args.robot).resolve()}
    if Path(args.out).resolve() in inputs:
        raise ValueError(f"{args.out}: this is an input; write the session to another file")
    meas = read_measurements(args.measurements)
    sf = SessionFile.create(args.out, Session.from_measurements(meas, load_robot(args.robot)))
    print(f"session {sf.path} created with {len(meas)} poses from {args.measurements}")
    return 0
