"""Sharing figures between this process and a forked copy: the split by cost, the order of the
paths, the progress callback, and a failed copy's figures drawn here."""

from __future__ import annotations

import multiprocessing
import os
import threading
from pathlib import Path

import pytest

import hexcal.diagnosis.figure_pool as figure_pool
from hexcal.diagnosis.figure_pool import FigureJob, draw_all, share

FORKS = (os.cpu_count() or 1) >= 2 and "fork" in multiprocessing.get_all_start_methods()


def _writer(text: str):
    def draw(path: Path) -> None:
        path.write_text(text)

    return draw


def test_share_balances_the_weights_and_keeps_the_order():
    jobs = [FigureJob(Path(f"{i}.png"), _writer(""), w) for i, w in enumerate([3, 1, 1, 1, 2, 2])]
    own, forked = share(jobs)
    assert sorted(own + forked, key=jobs.index) == jobs  # each job once
    assert sum(j.weight for j in own) == sum(j.weight for j in forked) == 5
    for side in (own, forked):
        assert side == sorted(side, key=jobs.index)


def test_share_of_one_heavy_job_against_many_light_ones():
    jobs = [FigureJob(Path("heavy.png"), _writer(""), 4.0)]
    jobs += [FigureJob(Path(f"{i}.png"), _writer(""), 1.0) for i in range(4)]
    own, forked = share(jobs)
    assert {len(own), len(forked)} == {1, 4}


@pytest.mark.parametrize("fork", [True, False])
def test_every_figure_is_written_and_reported_in_order(tmp_path, monkeypatch, fork):
    if fork and not FORKS:
        pytest.skip("figures are forked only on two cores or more, where processes fork")
    monkeypatch.setattr(threading, "active_count", lambda: 1)  # other tests' threads
    if not fork:
        monkeypatch.setattr(figure_pool, "_fork", lambda jobs: None)
    jobs = [FigureJob(tmp_path / f"{i}.txt", _writer(f"figure {i}"), 1 + i % 3) for i in range(7)]
    done: list[Path] = []
    paths = draw_all(jobs, done.append)
    assert paths == [j.path for j in jobs]
    assert sorted(done) == sorted(paths)  # each once, the fork's when it has ended
    assert [p.read_text() for p in paths] == [f"figure {i}" for i in range(7)]


def test_no_fork_while_other_threads_run(monkeypatch):
    monkeypatch.setattr(threading, "active_count", lambda: 2)
    assert figure_pool._fork([FigureJob(Path("x.png"), _writer(""))]) is None


@pytest.mark.skipif(not FORKS, reason="needs a fork")
def test_a_failed_copy_leaves_its_figures_here(tmp_path, monkeypatch):
    def failing(jobs):
        proc = multiprocessing.get_context("fork").Process(target=lambda: os._exit(3))
        proc.start()
        return proc

    monkeypatch.setattr(figure_pool, "_fork", failing)
    jobs = [FigureJob(tmp_path / f"{i}.txt", _writer(str(i))) for i in range(4)]
    assert [p.read_text() for p in draw_all(jobs)] == ["0", "1", "2", "3"]
