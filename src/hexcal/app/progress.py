"""Progress of the long jobs (diagnose, ``--auto``, plots and report, study) on the terminal.

One line on stderr that says what is being done, how far along it is and for how long: a rich
progress bar, drawn only when stderr is a terminal and the output is not ``--json`` (a pipe, a
log file or a JSON reader gets nothing). stdout is never touched, so the results stay clean.
rich comes with Textual; it is imported only when a bar is drawn.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, TextIO


class Progress:
    """A job's progress: :meth:`stage` starts a stage (``total`` steps, or None for one of
    unknown length), :meth:`advance` counts a step done. Silent when not drawn."""

    def __init__(self, bar: Any = None) -> None:
        self._bar = bar
        self._task: Any = None

    @property
    def shown(self) -> bool:
        return self._bar is not None

    def stage(self, text: str, total: int | None = None) -> None:
        if self._bar is None:
            return
        if self._task is not None:  # one line: the stage under way
            self._bar.remove_task(self._task)
        self._task = self._bar.add_task(text, total=total)

    def advance(self, steps: int = 1) -> None:
        if self._bar is not None and self._task is not None:
            self._bar.advance(self._task, steps)


def wanted(json_output: bool = False, stream: TextIO | None = None) -> bool:
    """Whether to draw: the stream (stderr) is a terminal and the output is not JSON."""
    stream = sys.stderr if stream is None else stream
    return not json_output and bool(getattr(stream, "isatty", lambda: False)())


@contextmanager
def progress(show: bool, stream: TextIO | None = None) -> Iterator[Progress]:
    """``with progress(wanted(args.json)) as p: p.stage("diagnosing Model 42"); ...``; the
    bar is removed when the job ends, whatever happens."""
    if not show:
        yield Progress()
        return
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        ProgressColumn,
        SpinnerColumn,
        TextColumn,
        TimeElapsedColumn,
    )
    from rich.progress import Progress as Bar
    from rich.text import Text

    class Count(ProgressColumn):  # "3/12", or nothing for a stage of unknown length
        def render(self, task: Any) -> Text:
            known = task.total is not None
            return Text(f"{int(task.completed)}/{int(task.total)}" if known else "")

    console = Console(file=sys.stderr if stream is None else stream, force_terminal=True)
    bar = Bar(
        SpinnerColumn(),
        TextColumn("{task.description}"),
        BarColumn(),
        Count(),
        TimeElapsedColumn(),
        console=console,
        transient=True,
    )
    with bar:
        yield Progress(bar)
