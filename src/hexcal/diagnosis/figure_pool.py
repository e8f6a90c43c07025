"""Drawing a set of figures on two cores: this process and one forked copy of it.

Drawing is most of a report's time (matplotlib spends about 0.2 s of one core on a six-panel
figure, and a two-step report has twenty-odd) and the figures are independent, so they are
shared between this process and a fork of it, by their expected cost. A fork shares the data
without pickling anything; the copy writes its PNGs and exits, and this process waits for it.
A fork is taken only where it is safe and pays: two cores or more, the ``fork`` start method
(not Windows, not macOS' default), and no other thread in this process (the text UI's workers:
a fork copies one thread only). A copy that fails leaves its figures to this process, which
draws them again, so that an error shows where it is seen.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class FigureJob:
    """One figure to draw: ``draw(path)`` writes the PNG at ``path``. ``weight``: its cost
    relative to a six-panel scatter figure (1), to share the jobs evenly."""

    path: Path
    draw: Callable[[Path], Any]
    weight: float = 1.0


def share(jobs: Sequence[FigureJob]) -> tuple[list[FigureJob], list[FigureJob]]:
    """(this process's jobs, the fork's): the heaviest first, each to the lighter side
    (longest processing time first), each side in the given order."""
    sides: tuple[list[int], list[int]] = ([], [])
    load = [0.0, 0.0]
    for i in sorted(range(len(jobs)), key=lambda i: -jobs[i].weight):
        side = 0 if load[0] <= load[1] else 1
        sides[side].append(i)
        load[side] += jobs[i].weight
    return [jobs[i] for i in sorted(sides[0])], [jobs[i] for i in sorted(sides[1])]


def draw_all(
    jobs: Sequence[FigureJob], on_done: Callable[[Path], None] | None = None
) -> list[Path]:
    """Draw every job, shared with a forked copy of this process where that is safe and pays
    (see the module's docstring); return the paths in the jobs' order. ``on_done`` is called
    with each path once its figure is written (this process's as each ends, the fork's when it
    has ended): a progress bar."""
    own, forked = share(jobs) if len(jobs) > 1 else (list(jobs), [])
    proc = _fork(forked) if forked else None
    if proc is None:
        own, forked = list(jobs), []
    for job in own:
        job.draw(job.path)
        if on_done is not None:
            on_done(job.path)
    if proc is not None:
        proc.join()
        for job in forked:
            if proc.exitcode != 0:  # drawn here after all, with the error where it is seen
                job.draw(job.path)
            if on_done is not None:
                on_done(job.path)
    return [job.path for job in jobs]


def _fork(jobs: Sequence[FigureJob]):
    """A started process drawing ``jobs`` (joined by the caller), or None where a fork is not
    safe or does not pay."""
    import multiprocessing
    import threading

    if (
        (os.cpu_count() or 1) < 2
        or threading.active_count() > 1
        or "fork" not in multiprocessing.get_all_start_methods()
    ):
        return None

    def draw() -> None:
        for job in jobs:
            job.draw(job.path)

    # What this process has buffered would otherwise be written twice: by it and by the copy.
    sys.stdout.flush()
    sys.stderr.flush()
    proc = multiprocessing.get_context("fork").Process(target=draw, daemon=True)
    proc.start()
    return proc
