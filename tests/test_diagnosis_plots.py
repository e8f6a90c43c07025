"""Residual plots of a diagnosis: every PNG is written, valid and non-trivial; the optional
ones degrade gracefully (no lead-screw pitch, no temperature); no figure is leaked."""

from __future__ import annotations

import dataclasses
import multiprocessing
import os

import matplotlib.pyplot as plt
import pytest

from hexcal.diagnosis.compare_plots import before_after
from hexcal.diagnosis.plots import PLOT_NAMES, leg_direction_angles, write_plots

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _is_png(path, min_bytes: int = 10_000) -> bool:
    data = path.read_bytes()
    return data.startswith(PNG_MAGIC) and len(data) > min_bytes


@pytest.fixture(scope="module")
def session(backlash_diagnoses):
    """A backlash session, diagnosed with Model 42 (verdict backlash) and + backlash (none)."""
    before, after, _, _ = backlash_diagnoses
    return before, after


@pytest.fixture(scope="module")
def written(session, tmp_path_factory):
    """All plots of the Model 42 fit and the before/after figure, written once."""
    before, after = session
    out = tmp_path_factory.mktemp("plots")
    paths = write_plots(before, out, prefix="m42_")
    ba = before_after(before, after, out)
    return out, paths, ba


def test_session_is_the_backlash_case(session):
    before, after = session
    assert before.verdict == "backlash"
    assert after.verdict == "none"


def test_every_plot_is_written_as_a_valid_png(written):
    out, paths, _ = written
    # The session has a temperature column, so nothing is skipped but the covariate plot: the
    # verdict names an effect, so no covariate was explored.
    assert [p.name for p in paths] == [
        "m42_" + n for n in PLOT_NAMES if n != "residuals_vs_covariate.png"
    ]
    for p in paths:
        assert p.parent == out and p.exists()
        assert _is_png(p), p.name


def test_before_after_is_a_valid_png(written):
    _, _, ba = written
    assert ba.name == "before_after.png"
    assert _is_png(ba, 30_000)


def test_no_figure_is_leaked_to_pyplot(written):
    # write_plots draws on Figure objects without pyplot, so pyplot's registry stays empty.
    assert plt.get_fignums() == []


def test_periodogram_without_a_pitch_is_drawn_without_the_marker(session, tmp_path):
    before, _ = session
    design = before.problem.design.model_copy(update={"leadscrew_pitch_mm": None})
    no_pitch = dataclasses.replace(
        before, problem=dataclasses.replace(before.problem, design=design)
    )
    paths = write_plots(no_pitch, tmp_path, only=["periodogram.png"])
    assert [p.name for p in paths] == ["periodogram.png"]
    assert _is_png(paths[0])


def test_temperature_plot_is_skipped_without_temperature(session, tmp_path):
    before, _ = session
    meas = before.problem.meas
    no_temp = dataclasses.replace(
        meas, temperature=None, columns=tuple(c for c in meas.columns if c != "temperature")
    )
    diag = dataclasses.replace(before, problem=dataclasses.replace(before.problem, meas=no_temp))
    assert write_plots(diag, tmp_path, only=["residuals_vs_temperature.png"]) == []
    assert list(tmp_path.iterdir()) == []


def test_unknown_plot_name_is_refused(session, tmp_path):
    with pytest.raises(ValueError, match="unknown plot"):
        write_plots(session[0], tmp_path, only=["nonsense.png"])


def test_leg_direction_angles_are_small_and_non_negative(session):
    ang = leg_direction_angles(session[0])
    assert ang.shape == (len(session[0].problem.meas), 6)
    assert (ang >= 0).all() and (ang < 45).all()


@pytest.mark.skipif(
    (os.cpu_count() or 1) < 2 or "fork" not in multiprocessing.get_all_start_methods(),
    reason="plots are forked only on two cores or more, where processes fork",
)
def test_the_plots_drawn_by_the_forked_process_are_those_drawn_here(session, tmp_path, monkeypatch):
    """Every other plot is drawn by a forked copy of the process (the second core): the files
    are byte for byte those drawn all in this process."""
    import threading

    import hexcal.diagnosis.figure_pool as figure_pool

    # Threads other tests left behind would make write_plots draw everything here.
    monkeypatch.setattr(threading, "active_count", lambda: 1)
    before, _ = session
    forked = write_plots(before, tmp_path / "forked")
    probe = figure_pool._fork(lambda: None)
    assert probe is not None  # the fork is taken here (one thread, two cores)
    probe.join()
    monkeypatch.setattr(figure_pool, "_fork", lambda jobs: None)
    serial = write_plots(before, tmp_path / "serial")
    assert [p.name for p in forked] == [p.name for p in serial]
    for a, b in zip(forked, serial, strict=True):
        assert a.read_bytes() == b.read_bytes(), a.name


def test_a_fork_that_fails_leaves_its_plots_to_this_process(session, tmp_path, monkeypatch):
    import hexcal.diagnosis.figure_pool as figure_pool

    def failing(jobs):
        proc = multiprocessing.get_context("fork").Process(target=lambda: os._exit(3))
        proc.start()
        return proc

    monkeypatch.setattr(figure_pool, "_fork", failing)
    paths = write_plots(session[0], tmp_path)
    assert paths and all(_is_png(p) for p in paths)
