"""Drawing figures in turns with a forked copy: the turns (costliest first, each figure once),
the order of the paths, the progress callback, and the figures of a copy that failed or died
drawn here."""

from __future__ import annotations

import errno
import multiprocessing
import os
import threading
import time
from pathlib import Path

import pytest

import hexcal.diagnosis.figure_pool as figure_pool
from hexcal.diagnosis.figure_pool import TAKEN_BY_COPY, TAKEN_HERE, FigureJob, _Turns, draw_all

FORKS = (os.cpu_count() or 1) >= 2 and "fork" in multiprocessing.get_all_start_methods()
needs_fork = pytest.mark.skipif(not FORKS, reason="figures are forked on two cores or more")


def _writer(text: str, log: Path | None = None, pause_s: float = 0.0):
    """A figure that writes ``text``, after ``pause_s``, and appends its drawer's pid to
    ``log`` (one short append: atomic between the two processes)."""

    def draw(path: Path) -> None:
        time.sleep(pause_s)
        path.write_text(text)
        if log is not None:
            # The figure is drawn into its temporary file, ".NAME.XXXXXXXX.tmp", then renamed.
            name = path.name.removeprefix(".").rsplit(".", 2)[0]
            with open(log, "a") as fh:
                fh.write(f"{name} {os.getpid()}\n")

    return draw


@needs_fork
def test_the_turns_give_each_figure_once_in_the_order_given_and_mark_who_took_it():
    turns = _Turns([2, 0, 1])
    assert turns.take(TAKEN_HERE) == 2 and turns.state[2] == TAKEN_HERE
    assert turns.take(TAKEN_BY_COPY) == 0 and turns.state[0] == TAKEN_BY_COPY
    assert turns.take(TAKEN_HERE) == 1
    assert turns.take(TAKEN_HERE) is None and turns.take(TAKEN_BY_COPY) is None


@pytest.mark.parametrize("fork", [True, False])
def test_every_figure_is_written_once_and_reported_once(tmp_path, monkeypatch, fork):
    """With the copy, the two processes share the figures (both draw some) and no figure is
    drawn twice; without it, this process draws them all in the jobs' order."""
    if fork and not FORKS:
        pytest.skip("figures are forked only on two cores or more, where processes fork")
    monkeypatch.setattr(threading, "active_count", lambda: 1)  # other tests' threads
    if not fork:
        monkeypatch.setattr(figure_pool, "_fork", lambda draw: None)
    log = tmp_path / "drawn.log"
    jobs = [
        FigureJob(tmp_path / f"{i}.txt", _writer(f"figure {i}", log, 0.05), 1 + i % 3)
        for i in range(8)
    ]
    done: list[Path] = []
    paths = draw_all(jobs, done.append)
    assert paths == [j.path for j in jobs]
    assert sorted(done) == sorted(paths)  # each once
    assert [p.read_text() for p in paths] == [f"figure {i}" for i in range(8)]
    drawn = [line.split() for line in log.read_text().splitlines()]
    assert sorted(name for name, _ in drawn) == sorted(p.name for p in paths)  # none twice
    drawers = {pid for _, pid in drawn}
    assert len(drawers) == (2 if fork else 1)
    if not fork:
        assert [name for name, _ in drawn] == [p.name for p in paths]


def test_no_fork_while_other_threads_run(monkeypatch):
    monkeypatch.setattr(threading, "active_count", lambda: 2)
    assert figure_pool._fork(lambda: None) is None


@needs_fork
def test_a_copy_that_fails_at_once_leaves_every_figure_here(tmp_path, monkeypatch):
    def failing(draw):
        proc = multiprocessing.get_context("fork").Process(target=lambda: os._exit(3))
        proc.start()
        return proc

    monkeypatch.setattr(figure_pool, "_fork", failing)
    jobs = [FigureJob(tmp_path / f"{i}.txt", _writer(str(i))) for i in range(4)]
    assert [p.read_text() for p in draw_all(jobs)] == ["0", "1", "2", "3"]


@needs_fork
def test_a_figure_the_copy_took_but_did_not_finish_is_drawn_here(tmp_path, monkeypatch):
    """The copy takes the first turn (the costliest figure) and dies before drawing it: this
    process draws it once the copy has ended, and reports it once."""
    monkeypatch.setattr(threading, "active_count", lambda: 1)
    taken = multiprocessing.get_context("fork").Event()

    real_take = _Turns.take

    def dying(jobs, turns, who):
        real_take(turns, who)
        taken.set()
        os._exit(3)

    monkeypatch.setattr(figure_pool, "_draw_turns", dying)

    def take_after_the_copy(self, who):  # this process waits for the copy's first turn
        assert taken.wait(10)
        return real_take(self, who)

    monkeypatch.setattr(_Turns, "take", take_after_the_copy)
    jobs = [FigureJob(tmp_path / f"{i}.txt", _writer(str(i)), w) for i, w in enumerate([1, 5, 2])]
    done: list[Path] = []
    paths = draw_all(jobs, done.append)
    assert [p.read_text() for p in paths] == ["0", "1", "2"]
    assert sorted(done) == sorted(paths)


def test_a_full_disk_is_one_message_naming_the_figure_and_leaves_no_figure(
    tmp_path, monkeypatch, capfd
):
    """The disk fills at the third figure: whoever meets it (the copy stops without a word and
    this process draws its figure again), the set ends in one error naming that figure's path,
    no traceback on stderr, and none of the set's figures nor a temporary file is left; a
    figure there before is kept."""
    from hexcal.io.fileio import OutputFileError

    monkeypatch.setattr(threading, "active_count", lambda: 1)

    def full(path: Path) -> None:
        path.write_bytes(b"\x89PNG cut")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    (tmp_path / "0.png").write_text("old")
    jobs = [
        FigureJob(tmp_path / f"{i}.png", full if i == 2 else _writer(str(i), None, 0.02), w)
        for i, w in enumerate([1, 1, 3, 1, 1])
    ]
    with pytest.raises(OutputFileError) as exc:
        draw_all(jobs)
    assert (
        str(exc.value) == f"{tmp_path / '2.png'}: the disk is full; free some space and try again"
    )
    assert "Traceback" not in capfd.readouterr().err
    assert [p.name for p in tmp_path.iterdir()] == ["0.png"]
    # Kept whole: replaced by its new figure where a process drew it before the disk filled,
    # or as it was where the set ended first (the costliest figure, the full one, is drawn
    # first, so which comes first is the machine's timing) — never cut, never removed.
    assert (tmp_path / "0.png").read_text() in ("0", "old")


def test_no_shared_memory_under_a_file_size_limit_draws_here_alone(tmp_path, monkeypatch):
    """The turns' shared memory is a file: beyond ``ulimit -f`` (or on a full /dev/shm) it
    cannot be had, and the figures are drawn here."""

    def refused(order):
        raise OSError(errno.EFBIG, os.strerror(errno.EFBIG))

    monkeypatch.setattr(figure_pool, "_Turns", refused)
    jobs = [FigureJob(tmp_path / f"{i}.txt", _writer(str(i))) for i in range(3)]
    assert [p.read_text() for p in draw_all(jobs)] == ["0", "1", "2"]
