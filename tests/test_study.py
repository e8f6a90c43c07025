"""`hexcal study`: the paper's protocol, batched; outputs written; behaviour against N and noise."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hexcal.app.cli import main
from hexcal.sim.study import METHODS, StudyConfig, run_study

SMALL = dict(trials=300, n_type_i=(4, 12), n_type_ii=(4, 12), n_type_iii=(5, 12))


def test_noise_free_study_is_exact():
    res = run_study(
        StudyConfig(
            trials=20,
            err_p_mm=0.0,
            err_a_deg=0.0,
            err_l_mm=0.0,
            n_type_i=(4, 6),
            n_type_ii=(4, 5),
            n_type_iii=(5, 6),
            n_free=(),  # the free-pose linear form's exactness: tests/test_solvers_free.py
        )
    )
    for r in res.rows:
        for key in ("base_err_mm", "platform_err_mm", "offset_err_mm"):
            if np.isfinite(r[key]):
                assert r[key] < 1e-9, r


@pytest.mark.slow
def test_errors_fall_with_n_and_scale_with_noise():
    res = run_study(StudyConfig(**SMALL))
    for pose_set, key in (
        ("type_i", "base_err_mm"),
        ("type_ii", "platform_err_mm"),
        ("type_iii", "base_err_mm"),
    ):
        for method in METHODS:
            _n, e = res.curve(pose_set, method, key)
            assert e[-1] < e[0], (pose_set, method)
    # First order: halving every noise halves the error (same random poses: same seed).
    half = run_study(StudyConfig(**SMALL, err_p_mm=0.05, err_a_deg=0.005, err_l_mm=0.05))
    for r, h in zip(res.rows, half.rows, strict=False):
        if r["set"] == "type_i" and r["n"] == 7:
            assert h["base_err_mm"] == pytest.approx(r["base_err_mm"] / 2, rel=0.02)


@pytest.mark.slow
def test_refined_is_at_least_as_good_as_paper_at_n7():
    res = run_study(
        StudyConfig(
            trials=1000, n_type_i=(7, 7), n_type_ii=(7, 7), n_type_iii=(7, 7), noise="gaussian"
        )
    )
    f = res.factors(7)
    # Mean errors from 1000 trials carry ~3 % standard error; 10 % is a 3-sigma margin.
    assert f["type_i"]["refined"]["base"] < f["type_i"]["paper"]["base"] * 1.1
    assert f["type_ii"]["refined"]["platform"] < f["type_ii"]["paper"]["platform"] * 1.1


@pytest.mark.slow
def test_cli_writes_csv_json_and_plots(tmp_path, capsys):
    rc = main(["study", "--trials", "50", "--out", str(tmp_path)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "factors at N = 7" in text and "≈13" in text
    for name in (
        "study.csv",
        "study.json",
        "study_type_i.png",
        "study_type_ii.png",
        "study_type_iii.png",
    ):
        assert (tmp_path / name).stat().st_size > 0
    data = json.loads((tmp_path / "study.json").read_text())
    assert data["config"]["trials"] == 50 and data["paper_factors"]["type_i"]["base"] == 13.0
    assert len([r for r in data["rows"] if r["set"] == "type_i"]) == 47 * 3


def test_nested_and_independent_designs_agree_within_their_standard_errors():
    """Nested pose sets (each trial's first N poses of one set) against a new set for every N,
    two independent runs (different seeds): on every curve (set, method, quantity) and at
    every N the mean errors agree within k = 4 standard errors of their difference.

    σ of a mean error over T trials: the trials' standard deviation of ‖error‖, from the row's
    own mean squared error and mean (var = E‖e‖² − (E‖e‖)², the offset's |e| alike), over
    √T; the difference of two
    independent runs has σ² = σ_nested² + σ_independent². About 160 comparisons at 4σ: under
    the null hypothesis all pass with probability 0.99 (the seeds are fixed: the test is
    deterministic, not flaky)."""
    small = dict(
        trials=300,
        n_type_i=(4, 12),
        n_type_ii=(4, 10),
        n_type_iii=(5, 10),
        n_free=(20, 30),
        trials_free=60,
    )
    nested = run_study(StudyConfig(**small, seed=11))
    indep = run_study(StudyConfig(**small, seed=12, nested=False))
    assert nested.config.nested and not indep.config.nested
    key = lambda r: (r["set"], r["n"], r["method"])  # noqa: E731
    rows_i = {key(r): r for r in indep.rows}
    assert sorted(rows_i) == sorted(key(r) for r in nested.rows)
    compared = 0
    for rn in nested.rows:
        ri = rows_i[key(rn)]
        t = small["trials_free"] if rn["set"] == "free" else small["trials"]
        for q in ("base", "platform", "offset"):
            mean_n, mean_i = rn[f"{q}_err_mm"], ri[f"{q}_err_mm"]
            mse_n, mse_i = rn[f"{q}_mse_mm2"], ri[f"{q}_mse_mm2"]
            if not np.isfinite(mean_n) or not np.isfinite(mse_n):
                continue
            var = (max(mse_n - mean_n**2, 0.0) + max(mse_i - mean_i**2, 0.0)) / t
            assert abs(mean_n - mean_i) <= 4.0 * np.sqrt(var), (key(rn), q, mean_n, mean_i)
            compared += 1
    assert compared > 150


def test_cli_independent_draws_a_set_per_n(tmp_path, monkeypatch):
    """``--independent`` reaches the study's config (the JSON says which design ran); the grid
    is shrunk to keep the test quick."""
    from dataclasses import replace

    import hexcal.sim.study as study_mod

    real = study_mod.run_study
    tiny = dict(n_type_i=(4, 5), n_type_ii=(4, 5), n_type_iii=(5, 6), n_free=(20,), trials_free=4)
    monkeypatch.setattr(
        study_mod,
        "run_study",
        lambda cfg, on_sweep=None: real(replace(cfg, **tiny), None, on_sweep),
    )
    for flag, nested in (([], True), (["--independent"], False)):
        out = tmp_path / str(nested)
        args = ["study", "--trials", "5", "--no-plots", "--json", "--out", str(out), *flag]
        assert main(args) == 0
        data = json.loads((out / "study.json").read_text())
        assert data["config"]["nested"] is nested


def test_log_axis_labels_in_plain_text_read_as_matplotlibs():
    """The figures' log axes label their ticks in plain text (no mathtext): each label reads
    as matplotlib's own mathtext label, its exponent in superscript digits."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import LogFormatterSciNotation

    from hexcal.sim.study import _plain_log_labels

    ax = Figure().subplots()
    ax.semilogy([1, 2], [0.15, 0.5])  # half a decade: matplotlib labels 2, 3, 4 and 6 × 10ⁿ
    ax.set_ylim(0.15, 0.5)
    _plain_log_labels(ax)
    major, minor = ax.yaxis.get_major_formatter(), ax.yaxis.get_minor_formatter()
    assert [major(x) for x in (0.01, 0.1, 1.0)] == ["10⁻²", "10⁻¹", "10⁰"]
    mathtext = LogFormatterSciNotation(10, labelOnlyBase=False)
    mathtext.set_axis(ax.yaxis)
    locs = [0.2, 0.3, 0.4, 0.5, 0.6]
    minor.set_locs(locs)
    mathtext.set_locs(locs)
    assert [minor(x) for x in locs] == ["2×10⁻¹", "3×10⁻¹", "4×10⁻¹", "", "6×10⁻¹"]
    assert [mathtext(x) for x in locs] == [
        rf"$\mathdefault{{{k}\times10^{{-1}}}}$" if k else "" for k in ("2", "3", "4", "", "6")
    ]
