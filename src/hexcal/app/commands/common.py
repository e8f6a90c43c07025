"""What the ``hexcal`` commands share: exit statuses, the option types (every number that enters
is finite and in range), reading the workflow's inputs, the drawing check's report and the
refusal to overwrite."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hexcal.io.capacity import MAX_POSES_PER_STEP

EXIT_INPUT = 2  # bad input: a file, a field or a pose set the user must fix
EXIT_REFUSED = 3  # the data cannot calibrate the robot: more or other poses are needed
EXIT_DRAWING = 4  # the calibration fits but does not match the drawing (swapped legs, …)
EXIT_INTERNAL = 1  # a fault of hexcal's own: the message says how to report it


# -- option types: every number that enters is finite and in range ---------------------------
def number(kind: type, lo: float | None = None, hi: float | None = None, lo_open: bool = False):
    """An argparse type: ``kind`` (int or float), finite, within [lo, hi] (lo excluded when
    ``lo_open``), with a message naming the allowed range."""
    import math

    def parse(text: str):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{text!r} is not {'an integer' if kind is int else 'a number'}"
            ) from None
        if not math.isfinite(v):
            raise argparse.ArgumentTypeError(f"{text!r} is not finite")
        below = lo is not None and (v <= lo if lo_open else v < lo)
        if below or (hi is not None and v > hi):
            left = "(" if lo_open else "["
            raise argparse.ArgumentTypeError(f"{text} is outside {left}{lo:g}, {hi:g}]")
        return v

    parse.__name__ = kind.__name__
    return parse


COUNT = number(int, 0, 100_000)  # poses or trials
#: A simulated session's free poses: a lab's motion capture at 100 Hz gives 120,000 in twenty
#: minutes, and hexcal's fit is linear in the poses (docs/performance.md).
SESSION_POSES = number(int, 0, 1_000_000)
POSITIVE_COUNT = number(int, 1, 100_000)
#: A step's poses (``--poses-per-step``, ``--free-poses``): the procedure file's own cap.
POSES_PER_STEP = number(int, 1, MAX_POSES_PER_STEP)
#: The free steps' poses (``--free-poses``; 0: the procedure's count), under the same cap.
FREE_POSES = number(int, 0, MAX_POSES_PER_STEP)
SEED = number(int, 0, 2**32 - 1)
SIGMA = number(float, 0.0, 1000.0)
SECONDS = number(float, 0.0, 60.0, lo_open=True)
POSE_ID = number(int, 0, 2**53)


def read_inputs(args: argparse.Namespace):
    """The workflow's inputs from the command's files; a calibrated.json given as --robot
    brings its effects (said on stderr)."""
    from hexcal.app.workflow import read_inputs as read_workflow_inputs

    inp = read_workflow_inputs(args.measurements, args.robot, args.instruments)
    for text in inp.notices:
        print(f"hexcal: {text}", file=sys.stderr)
    if getattr(args, "exclude_poses", None):
        inp = inp.without(args.exclude_poses)
    if hasattr(args, "no_drawing_check"):
        # The cheap checks before any fit (units, signs, quaternion order, the drawing):
        # refused at once, or, resting on a drawing not checked, said and gone on.
        from hexcal.app.workflow import screen_inputs
        from hexcal.errors import MismatchError

        inp.drawing_check = not args.no_drawing_check
        inp.drawing_tolerance = args.drawing_tolerance
        try:
            inp.warnings = screen_inputs(inp)
        except MismatchError as exc:
            if getattr(args, "out", None):
                raise type(exc)(f"{exc}; {args.out} was not written") from None
            raise
        for text in inp.warnings:
            print(f"hexcal: warning (the drawing is not checked): {text}", file=sys.stderr)
    if inp.model_effects and not getattr(args, "json", False):
        print(
            f"hexcal: {args.robot} is a calibrated model: its effects "
            f"({', '.join(inp.model_effects)}) are part of the model",
            file=sys.stderr,
        )
    return inp


def drawing_tolerance(args: argparse.Namespace) -> float | None:
    """The drawing check's tolerance, None with --no-drawing-check."""
    return None if args.no_drawing_check else args.drawing_tolerance


def report_mismatch(mismatch: list[str], args: argparse.Namespace) -> int:
    """0 when the calibration matches the drawing, else the mismatch on stderr and
    :data:`EXIT_DRAWING`."""
    if not mismatch:
        return 0
    lines = "\n".join(f"  {m}" for m in mismatch)
    unwritten = f"; {args.out} was not written" if getattr(args, "out", None) else ""
    print(
        f"hexcal: the calibration fits the data but does not match the drawing{unwritten}:\n"
        f"{lines}\nfix the cause and calibrate again; if the drawing itself is wrong, "
        "--drawing-tolerance or --no-drawing-check",
        file=sys.stderr,
    )
    return EXIT_DRAWING


def check_outputs(*outputs: tuple[object, str]) -> None:
    """Refuse, before any work, an output path that cannot be written: each ``(path, what)``
    with ``what`` a file name to suggest inside a folder given where a file is wanted (e.g.
    ``calibrated.json``), or ``"/"`` for an output folder; None paths are skipped."""
    from hexcal.io.fileio import check_output

    for path, what in outputs:
        if path:
            check_output(Path(str(path)), folder=what == "/", example=what)


def refuse_existing(directory: Path, names: list[str], force: bool) -> None:
    """An output directory whose files would be replaced needs --force; a file where the
    directory should be is refused by name (not "File exists" from mkdir)."""
    if Path(directory).exists() and not Path(directory).is_dir():
        raise ValueError(
            f"{directory}: is a file; --out needs a directory (it writes {' and '.join(names)} "
            "into it): give a new or existing directory's path"
        )
    there = [n for n in names if (Path(directory) / n).exists()]
    if there and not force:
        raise ValueError(
            f"{directory}: already holds {', '.join(there)}; pass --force to replace them, or "
            "choose another --out"
        )


def add_pose_selection(p: argparse.ArgumentParser) -> None:
    """The options calibrate and diagnose share for which poses count and how the result is
    checked against the drawing: --exclude-poses, --drawing-tolerance, --no-drawing-check."""
    p.add_argument(
        "--exclude-poses",
        nargs="+",
        type=POSE_ID,
        metavar="ID",
        help="leave these pose ids out (e.g. the gross outliers hexcal names)",
    )
    p.add_argument(
        "--drawing-tolerance",
        type=number(float, 0.0, 10.0, lo_open=True),
        default=0.10,
        help="how far a fitted point may lie from its design point, as a fraction of the "
        "design radius (default 0.10); a leg beyond it, or nearer another leg's design, stops "
        "with exit status 4",
    )
    p.add_argument(
        "--no-drawing-check",
        action="store_true",
        help="do not compare the calibration with the drawing (swapped legs go unnoticed)",
    )


def print_help_of(parser: argparse.ArgumentParser) -> None:
    """A command group given no subcommand prints its subcommands (exit 0) instead of an error."""

    def show(args: argparse.Namespace) -> int:
        parser.print_help()
        return 0

    parser.set_defaults(func=show)


def add_model_option(parser: argparse.ArgumentParser) -> None:
    """``--model 36|42``, as calibrate and diagnose take it."""
    parser.add_argument(
        "--model",
        type=int,
        choices=(36, 42),
        default=42,
        help="36: base and platform points; 42: and each leg's length offset (default 42)",
    )


def add_effects_option(parser: argparse.ArgumentParser) -> None:
    """``--effects FILE.py …``: effects from outside the catalogue, as calibrate, diagnose,
    validate, predict and simulate take them (docs/effects.md)."""
    parser.add_argument(
        "--effects",
        nargs="+",
        type=Path,
        metavar="FILE.py",
        help="Python files defining effects beyond the catalogue (docs/effects.md); they run as "
        "your own code. Installed effect packages load without it",
    )


def load_effects(args: argparse.Namespace) -> list[str]:
    """Run the ``--effects`` files (the user's explicit act) and say, on stderr, which
    installed effect packages failed to load; the names the files registered."""
    from hexcal.effects.plugins import failures, load_files

    for text in failures():
        print(f"hexcal: {text}", file=sys.stderr)
    return load_files(getattr(args, "effects", None) or ())
