"""The commands hexcal prints for its user to run — "Find what:", "Next:", the demo's next step,
the examples' first command, how to merge a conflicting save — built in one place, so that each
runs as printed:

- it carries the user's own inputs (the table, ``--robot``, ``--instruments``, ``--effects``,
  the poses left out, the model and the drawing check), read from the command's parsed
  arguments, and none of its outputs (``--out``, ``--report``, ``--plots``…: running the advice
  must not write over what the first command wrote);
- an output it names is one that is not there yet (:func:`free_path`);
- it is quoted as a POSIX shell reads it back (:func:`shlex.join`), and printed alone on its
  line after :data:`INDENT`, never wrapped, so it can be copied whole.

``tests/test_advice.py`` collects every line so printed over the examples and the docs'
sessions and runs it.

Here, at the bottom of the data flow, because the session file (procedure) gives advice too;
it needs no more than :mod:`argparse`'s namespace and :mod:`shlex`.
"""

from __future__ import annotations

import argparse
import re
import shlex
from collections.abc import Iterable
from pathlib import Path

#: An advised command's line starts with this, the command right after it.
INDENT = "  "
#: The model calibrate and diagnose fit unless told (``--model``).
DEFAULT_MODEL = 42
#: How far a fitted point may lie from its design point unless told (``--drawing-tolerance``),
#: as a fraction of the design radius.
DEFAULT_DRAWING_TOLERANCE = 0.10

#: An advised command as printed: indented, then ``hexcal …`` or ``cd DIR && hexcal …``.
ADVICE_LINE = re.compile(r"^  ((?:cd .+? && )?hexcal [a-z].*)$")

#: The inputs calibrate and diagnose share that an advised command carries over, as
#: (attribute, option): the data and the model, never an output.
_CARRIED = (
    ("robot", "--robot"),
    ("instruments", "--instruments"),
    ("effects", "--effects"),
    ("exclude_poses", "--exclude-poses"),
    ("exclude_at_limits", "--exclude-at-limits"),
    ("no_drawing_check", "--no-drawing-check"),
)


def command(*words: object) -> str:
    """``hexcal`` and ``words``, quoted as a POSIX shell reads them back."""
    return shlex.join(["hexcal", *(str(w) for w in words)])


def line(cmd: str) -> str:
    """``cmd`` as printed for the user to run: alone on its line, after :data:`INDENT`."""
    return INDENT + cmd


def is_line(text: str) -> bool:
    """Whether ``text`` is an advised command's line (printed whole, never re-wrapped)."""
    return bool(ADVICE_LINE.match(text))


def input_words(args: argparse.Namespace) -> list[str]:
    """The user's inputs from a calibrate or diagnose command's parsed ``args``, as words of a
    command line: the table first, then each option given (none of the outputs)."""
    words = [str(args.measurements)]
    for attr, option in _CARRIED:
        value = getattr(args, attr, None)
        if value is None or value is False or value == []:
            continue
        if value is True:
            words.append(option)
        elif isinstance(value, list | tuple):
            words += [option, *(str(v) for v in value)]
        else:
            words += [option, str(value)]
    if getattr(args, "model", DEFAULT_MODEL) != DEFAULT_MODEL:
        words += ["--model", str(args.model)]
    tolerance = getattr(args, "drawing_tolerance", DEFAULT_DRAWING_TOLERANCE)
    if tolerance != DEFAULT_DRAWING_TOLERANCE:
        words += ["--drawing-tolerance", f"{tolerance:g}"]
    return words


def diagnose_command(
    args: argparse.Namespace,
    add: Iterable[str] = (),
    auto: bool = False,
    effects: Iterable[str | Path] = (),
    effect_file: Path | None = None,
) -> str:
    """``hexcal diagnose`` on the inputs of ``args`` (a calibrate or diagnose command's), with
    the effects it already had (its ``--add``) and ``add``; ``auto``: add what is named until
    nothing is; ``effects``: more ``--effects`` files; ``effect_file``: write one there."""
    words = ["diagnose", *input_words(args)]
    files = [str(f) for f in effects if str(f) not in words]
    if files:
        if "--effects" in words:  # one --effects option: argparse keeps the last one given
            at = words.index("--effects") + 1
            while at < len(words) and not words[at].startswith("--"):
                at += 1
            words[at:at] = files
        else:
            words += ["--effects", *files]
    effects_added = list(dict.fromkeys([*(getattr(args, "add", None) or ()), *add]))
    if effects_added:
        words += ["--add", *effects_added]
    if auto:
        words.append("--auto")
    if effect_file is not None:
        words += ["--effect-file", str(effect_file)]
    return command(*words)


def free_path(path: Path) -> Path:
    """``path`` when nothing is there, else the first free of ``stem-2.ext``, ``stem-3.ext``…:
    the output an advice names never writes over an earlier one."""
    path = Path(path)
    n = 2
    found = path
    while found.exists():
        found = path.with_name(f"{path.stem}-{n}{path.suffix}")
        n += 1
    return found


def beside(source: str | Path, what: str, suffix: str) -> Path:
    """An output named after its input, next to it and free: ``s2.json`` → ``s2-report.html``
    (``what`` "report", ``suffix`` ".html"), so two sessions' reports never share a name."""
    source = Path(source)
    return free_path(source.with_name(f"{source.stem}-{what}{suffix}"))
