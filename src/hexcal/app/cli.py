"""The ``hexcal`` command line: calibrate, diagnose, devices, study, simulate, demo, session,
schema.

Each command is a module of :mod:`hexcal.app.commands` (its options and what it does); this module
builds the parser from them and runs one. Errors go to stderr with a non-zero exit status;
``--json`` prints one JSON object on stdout.
"""

from __future__ import annotations

import argparse
import sys

from hexcal.app.commands import COMMANDS
from hexcal.app.commands.common import COUNT as COUNT
from hexcal.app.commands.common import EXIT_DRAWING as EXIT_DRAWING
from hexcal.app.commands.common import EXIT_INPUT, EXIT_INTERNAL, EXIT_REFUSED
from hexcal.app.commands.common import POSE_ID as POSE_ID
from hexcal.app.commands.common import POSITIVE_COUNT as POSITIVE_COUNT
from hexcal.app.commands.common import SECONDS as SECONDS
from hexcal.app.commands.common import SEED as SEED
from hexcal.app.commands.common import SIGMA as SIGMA


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The command line's parser: every command, or only the command named ``only`` (what a
    command's run needs: building the fourteen commands' options is 10 ms of its start)."""
    from hexcal import __version__

    p = argparse.ArgumentParser(
        prog="hexcal", description="Calibrate Gough-Stewart platforms (units: mm, deg)."
    )
    p.add_argument("--version", action="version", version=f"hexcal {__version__}")
    sub = p.add_subparsers(dest="command", metavar="command")
    for command in COMMANDS:
        if only is None or command.NAME == only:
            command.add_parser(sub)
    return p


#: The thread-count variables of the BLAS libraries numpy may be built with.
BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def single_thread_blas() -> bool:
    """One BLAS thread, as every ``hexcal`` command runs (the benchmarks and the tests apply
    this too). The problems here are small (a few hundred poses): BLAS threads cost more than
    they give (measured: diagnose 0.81 s with one thread, 0.91 s with two), and they
    oversubscribe the cores when several hexcal processes run. The user's own setting wins.

    BLAS reads these variables when it loads: False when numpy was imported already (then the
    setting applies only to the processes started from here)."""
    import os

    for var in BLAS_THREAD_VARS:
        os.environ.setdefault(var, "1")
    return "numpy" not in sys.modules


def main(argv: list[str] | None = None) -> int:
    import os

    single_thread_blas()
    argv = sys.argv[1:] if argv is None else argv
    # A command named first needs its own options only; anything else (no command, --help,
    # --version, a misspelt command) gets them all, so that the help and errors list them.
    named = argv[0] if argv and argv[0] in {c.NAME for c in COMMANDS} else None
    parser = build_parser(named)
    args = parser.parse_args(argv)
    if args.command is None:  # hexcal alone: what it can do
        parser.print_help()
        return 0
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print("hexcal: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # one error path: a message and an exit status, no traceback
        code, message = error_message(exc)
        print(f"hexcal: {message}", file=sys.stderr)
        if code == EXIT_INTERNAL and os.environ.get("HEXCAL_DEBUG"):
            raise
        return code


def error_message(exc: BaseException) -> tuple[int, str]:
    """(exit status, message) for an exception reaching the command line. hexcal's own errors
    name the file, line, field or device already; library errors are put in words here, so no
    raw library text reaches the user."""
    import numpy as np

    from hexcal.errors import HexcalError, MismatchError, RefusedError

    if isinstance(exc, MismatchError):  # the data against the drawing or themselves
        return EXIT_DRAWING, str(exc)
    if isinstance(exc, RefusedError):
        return EXIT_REFUSED, str(exc)
    if isinstance(exc, HexcalError):  # its message names what and says what to do
        return EXIT_INPUT, str(exc)
    if isinstance(exc, np.linalg.LinAlgError):
        return EXIT_REFUSED, (
            "the poses do not determine the geometry (the system to solve is singular); record "
            "poses that move every leg over its stroke and change its direction, or check the "
            "table for repeated or constant columns"
        )
    if isinstance(exc, RecursionError):
        return EXIT_INPUT, (
            "an input is nested too deeply to read (RecursionError); check the files given"
        )
    if isinstance(exc, MemoryError):
        # Reading a file and fitting a long session both end here: say both.
        return EXIT_INPUT, (
            "out of memory (MemoryError): a file given is far larger than it should be, or the "
            "session is too long for this machine (diagnose holds about 14 kB a pose, calibrate "
            "about 3 kB: docs/performance.md); check the files, or diagnose a part of the poses"
        )
    if isinstance(exc, UnicodeDecodeError):
        return EXIT_INPUT, f"an input is not UTF-8 text (byte {exc.start}); save it as UTF-8"
    if isinstance(exc, OSError):
        where = f"{exc.filename}: " if exc.filename else ""
        return EXIT_INPUT, f"{where}{exc.strerror or exc}"
    if isinstance(exc, ValueError):
        return EXIT_INPUT, str(exc)
    return EXIT_INTERNAL, (
        f"internal error ({type(exc).__name__}: {exc}); this is a fault in hexcal, not in your "
        "data: please report it with the command line (HEXCAL_DEBUG=1 shows the traceback)"
    )


def command() -> int:
    """The ``hexcal`` program: :func:`main` in a process of its own, with the garbage collector
    set for a short-lived one. Its collections are rarer (as mypy's are): a report makes some
    hundred thousand matplotlib objects, and collecting them every 700 allocations was 0.3 s of
    a 3 s ``diagnose --report``; and at the end the objects are frozen, so the interpreter's
    exit does not walk them once more. Arrays are still freed by reference count; only cyclic
    garbage waits longer (the peak memory at 120,000 poses is in docs/performance.md)."""
    import gc

    gc.set_threshold(200_000, 30, 30)
    try:
        return main()
    finally:
        gc.freeze()


if __name__ == "__main__":
    sys.exit(command())
