"""Drawing a set of figures on two cores: this process and one forked copy of it.

Drawing is most of a report's time (matplotlib spends about 0.2 s of one core on a six-panel
figure, and a two-step report has twenty-odd) and the figures are independent, so this process
and a fork of it draw them in turns: each takes the next figure not yet taken (the costliest
first, so that the last to end is a cheap one) until none is left, and both end together
whatever each figure costs. A fork shares the data without pickling anything; the copy writes
its PNGs and exits, and this process waits for it. A fork is taken only where it is safe and
pays: two cores or more, the ``fork`` start method (not Windows, not macOS' default), and no
other thread in this process (the text UI's workers: a fork copies one thread only). A figure
the copy took but did not finish (it failed, or died) is drawn again here, so that an error
shows where it is seen: the copy stops at its first failure without a word (no traceback of
its own), and this process meets the same failure, as one message naming the file.

Each PNG is written to a temporary file beside it and renamed
(:func:`hexcal.io.fileio.write_atomic_with`): a full disk or a file-size limit leaves no
figure cut short. When this process fails, the copy is told to take no more figures and is
waited for, so that nothing is written after the error.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: How long this process waits for its turn (s) before it takes the copy for dead: a turn is
#: taken in microseconds, so only a copy killed while taking one holds it longer.
TURN_TIMEOUT_S = 10.0
#: A figure's state in the turns (:class:`_Turns`).
FREE, TAKEN_BY_COPY, DRAWN_BY_COPY, TAKEN_HERE = 0, 1, 2, 3


@dataclass(frozen=True)
class FigureJob:
    """One figure to draw: ``draw(path)`` writes the PNG at ``path``. ``weight``: its expected
    cost relative to a six-panel scatter figure (1); the costliest are taken first."""

    path: Path
    draw: Callable[[Path], Any]
    weight: float = 1.0


class _Turns:
    """The figures' turns, in memory shared with the forked copy: which figure is next, and
    the state of each (:data:`FREE` … :data:`TAKEN_HERE`)."""

    def __init__(self, order: Sequence[int]):
        import multiprocessing

        ctx = multiprocessing.get_context("fork")
        self.order = list(order)
        self._next = ctx.Value("i", 0)  # with its own lock
        self.state = ctx.Array("b", len(self.order), lock=False)

    def take(self, who: int) -> int | None:
        """The next figure (its index among the jobs), marked as taken by ``who`` in the same
        step, so that a copy that dies after taking it leaves it marked; None once every figure
        is taken, or when the turn is held too long (the copy died holding it)."""
        lock = self._next.get_lock()
        if not lock.acquire(timeout=TURN_TIMEOUT_S):
            return None
        try:
            k = self._next.value
            if k >= len(self.order):
                return None
            self._next.value = k + 1
            self.state[self.order[k]] = who
            return self.order[k]
        finally:
            lock.release()

    def stop(self) -> None:
        """Leave no figure to take: the copy ends after the one it is drawing."""
        with self._next.get_lock():
            self._next.value = len(self.order)


def draw_all(
    jobs: Sequence[FigureJob], on_done: Callable[[Path], None] | None = None
) -> list[Path]:
    """Draw every job, in turns with a forked copy of this process where that is safe and pays
    (see the module's docstring); return the paths in the jobs' order. ``on_done`` is called
    once with each path when its figure is written: this process's as each ends, the copy's as
    this process sees them between its own and when the copy has ended (a progress bar).
    When a figure fails, the figures of this set written by then that were not there before are
    removed: a failed set leaves none of its new files."""
    there = {job.path for job in jobs if job.path.exists()}
    try:
        return _draw_set(jobs, on_done)
    except BaseException:
        for job in jobs:
            if job.path not in there:
                job.path.unlink(missing_ok=True)
        raise


def _draw_set(jobs: Sequence[FigureJob], on_done: Callable[[Path], None] | None) -> list[Path]:
    """:func:`draw_all`'s drawing."""
    order = sorted(range(len(jobs)), key=lambda i: -jobs[i].weight)
    turns = _shared_turns(order) if len(jobs) > 1 and _forks() else None
    proc = None if turns is None else _fork(lambda: _draw_turns(jobs, turns, TAKEN_BY_COPY))
    if turns is None or proc is None:
        for job in jobs:
            _draw(job)
            if on_done is not None:
                on_done(job.path)
        return [job.path for job in jobs]
    told: set[int] = set()

    def tell(i: int) -> None:
        if on_done is not None and i not in told:
            on_done(jobs[i].path)
        told.add(i)

    try:
        while (i := turns.take(TAKEN_HERE)) is not None:
            _draw(jobs[i])
            tell(i)
            for j in range(len(jobs)):
                if turns.state[j] == DRAWN_BY_COPY:
                    tell(j)
    except BaseException:
        turns.stop()
        proc.join()
        raise
    proc.join()
    for i in range(len(jobs)):
        if turns.state[i] in (FREE, TAKEN_BY_COPY):  # the copy's unfinished, or never taken
            _draw(jobs[i])
        tell(i)
    return [job.path for job in jobs]


def _shared_turns(order: Sequence[int]) -> _Turns | None:
    """The turns in shared memory, or None (draw here alone) where it cannot be had: its
    backing file beyond this process's file-size limit (ulimit -f) or on a full disk."""
    try:
        return _Turns(order)
    except OSError:
        return None


def _draw(job: FigureJob) -> None:
    """Draw one figure into a temporary file and rename it to its path."""
    from hexcal.io.fileio import write_atomic_with, write_error

    try:
        job.path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise write_error(exc, job.path.parent) from None
    write_atomic_with(job.path, job.draw)


def _draw_turns(jobs: Sequence[FigureJob], turns: _Turns, who: int) -> None:
    """The copy's part: take the next figure and draw it until none is left. At a failure it
    stops quietly, the figure left marked as taken by it: this process draws it again and
    meets the failure where its message is seen."""
    try:
        while (i := turns.take(who)) is not None:
            _draw(jobs[i])
            turns.state[i] = DRAWN_BY_COPY
    except Exception:
        return


def _forks() -> bool:
    """Whether processes can be forked here (not on Windows, nor by macOS' default)."""
    import multiprocessing

    return "fork" in multiprocessing.get_all_start_methods()


def _fork(draw: Callable[[], None]):
    """A started forked process running ``draw`` (joined by the caller), or None where a fork
    is not safe or does not pay: fewer than two cores, or another thread in this process (a
    fork copies one thread only; the text UI's workers)."""
    import multiprocessing
    import threading

    if (os.cpu_count() or 1) < 2 or threading.active_count() > 1 or not _forks():
        return None
    # What this process has buffered would otherwise be written twice: by it and by the copy.
    sys.stdout.flush()
    sys.stderr.flush()
    proc = multiprocessing.get_context("fork").Process(target=draw, daemon=True)
    proc.start()
    return proc
