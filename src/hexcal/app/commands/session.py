"""``hexcal session``: export a session file, make one from a CSV, or merge two versions."""

from __future__ import annotations

import argparse
from pathlib import Path

from hexcal.app.commands.common import print_help_of, refuse_existing

#: The command's name on the command line.
NAME = "session"


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``session`` group: ``export``, ``import``, ``merge``."""
    se = sub.add_parser(NAME, help="export a session file, or make one from a CSV")
    se_sub = se.add_subparsers(dest="session_command", metavar="{export,import,merge}")
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
    me = se_sub.add_parser(
        "merge",
        help="two versions of one session (a save that met another program's change) as one",
    )
    me.add_argument("theirs", type=Path, help="the session file on disk")
    me.add_argument("mine", type=Path, help="the version saved beside it (NAME.mine.json)")
    me.add_argument("--out", type=Path, required=True, help="session file to create")
    me.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from hexcal.estimate.model_file import load_robot
    from hexcal.io.fileio import check_output
    from hexcal.procedure.session import SessionFile, export_session, import_table, load_session
    from hexcal.vocabulary import counted

    if args.session_command == "export":
        check_output(args.out, folder=True)
        names = ["measurements.csv", "robot.json", "instruments.json", "calibrated.json"]
        if any((Path(args.out) / n).resolve() == Path(args.session).resolve() for n in names):
            raise ValueError(
                f"{args.session}: the export would replace the session; choose another --out"
            )
        refuse_existing(args.out, names, args.force)
        written = export_session(load_session(args.session), args.out)
        print(f"exported {args.session} to {Path(args.out)}/: {', '.join(written)}")
        return 0
    inputs = [args.measurements, args.robot] if args.session_command == "import" else []
    inputs += [args.theirs, args.mine] if args.session_command == "merge" else []
    if Path(args.out).resolve() in {Path(p).resolve() for p in inputs}:
        raise ValueError(f"{args.out}: this is an input; write the session to another file")
    check_output(args.out, example="session.json")
    if args.session_command == "merge":
        from hexcal.procedure.session_merge import merge_sessions

        merged, said = merge_sessions(load_session(args.theirs), load_session(args.mine))
        with SessionFile.create(args.out, merged) as sf:
            added = ", ".join(said) if said else "nothing: mine adds nothing to theirs"
            print(f"session {sf.path} created from {args.theirs}, with from {args.mine}: {added}")
        return 0
    # Streamed into the session's pose block: memory does not grow with the table, and a
    # table beyond what a session holds is refused with nothing written.
    path, n = import_table(args.measurements, load_robot(args.robot), args.out)
    print(f"session {path} created with {counted(n, 'pose')} from {args.measurements}")
    return 0
