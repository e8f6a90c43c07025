"""``hexcal examples``: write the example inputs shipped inside hexcal (``hexcal.examples``: the
repository's examples/ folder) to a directory, so a pip user can run the commands the docs give.
"""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # importlib.resources.abc is Python 3.11+; this name serves 3.10 too
    from importlib.abc import Traversable

#: What is package machinery, not an example.
_NOT_EXAMPLES = {"__init__.py", "__pycache__"}


#: The command's name on the command line.
NAME = "examples"


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``examples`` command and its options."""
    p = sub.add_parser(
        NAME,
        help="write the examples (simulated sessions, the Jugglebot's log, a rig file) to a directory",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=Path("hexcal-examples"),
        help="directory to write them to (default: ./hexcal-examples)",
    )
    p.add_argument("--force", action="store_true", help="replace files that exist there")
    p.set_defaults(func=run)


def example_files() -> dict[str, str]:
    """Every shipped example file: its path relative to the examples folder (``/``-separated)
    → its text (UTF-8, its line ends as shipped)."""
    files: dict[str, str] = {}

    def walk(node: Traversable, prefix: str) -> None:
        for child in sorted(node.iterdir(), key=lambda c: c.name):
            if child.name == "__pycache__" or (not prefix and child.name in _NOT_EXAMPLES):
                continue  # the examples folder's own package file; an example's are kept
            if child.is_dir():
                walk(child, f"{prefix}{child.name}/")
            else:
                # As shipped, line ends included (the Jugglebot's log is copied unchanged).
                files[f"{prefix}{child.name}"] = child.read_bytes().decode("utf-8")

    # Imported here: importlib.resources (tempfile, shutil, the compressors) is 10 ms of every
    # hexcal command's start otherwise, since the parser imports every command's module.
    from importlib import resources

    walk(resources.files("hexcal.examples"), "")
    return files


def run(args: argparse.Namespace) -> int:
    from hexcal.io.fileio import write_files_atomic

    out: Path = args.out
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out}: is a file, not a directory; choose another --out")
    files = example_files()
    there = [name for name in files if (out / name).exists()]
    if there and not args.force:
        raise ValueError(
            f"{out}: already holds {len(there)} of the examples' {len(files)} files (e.g. "
            f"{there[0]}); pass --force to replace them, or choose another --out"
        )
    write_files_atomic(out, files)  # all or nothing: a failure leaves no part of them
    folders = sorted({name.split("/")[0] for name in files if "/" in name})
    print(f"hexcal's examples written to {out}/: {', '.join(f + '/' for f in folders)}")
    print(f"{out / 'README.md'} says what each is and the command to run inside it, e.g.:")
    from hexcal.io.advice import command, line

    diagnose = command(
        "diagnose",
        "measurements.csv",
        "--robot",
        "robot.json",
        "--instruments",
        "instruments.json",
        "--auto",
    )
    print(line(f"cd {shlex.quote(str(out / 'left-hand-backlash'))} && {diagnose}"))
    return 0
