"""Gross outliers as a verdict of their own: poses no model explains are found, set aside (not
deleted) and named; the rest of the session is diagnosed without them. A bumped tracker is
simulated as the measured position of three random poses displaced by 0.5 mm in a random
direction, with the instruments' noise of the tests stated (tracker 10 µm, 0.002°; encoders
2 µm, 1σ)."""

from __future__ import annotations

import csv
import io

import numpy as np
import pytest
from conftest import instruments
from statcheck import floor_limit

from hexcal.app.workflow import Inputs, diagnose_chain
from hexcal.diagnosis import diagnose
from hexcal.diagnosis.outliers import (
    OUTLIER_ALPHA,
    Subset,
    find_outliers,
    outlier_threshold,
    pose_residuals,
)
from hexcal.estimate.effect_fit import Problem, fit_model
from hexcal.model.noise import NoiseSigmas
from hexcal.sim.inject import effect_hook, realistic_values
from hexcal.sim.session_sim import SessionPlan, bump_poses, perturbed_truth, simulate_session

INST = instruments()
PLAN = SessionPlan(temperature_rise_k=5.0)


def _session(design, seed: int, effect: str | None = None, n_bumped: int = 3):
    """A simulated session hiding ``effect``, with ``n_bumped`` poses' measured positions
    displaced by 0.5 mm in a random direction: (measurements, design, bumped rows)."""
    design = design.model_copy(update={"platform_mass_kg": 20.0})
    rng = np.random.default_rng(seed)
    truth = perturbed_truth(design, rng, PLAN)
    hooks = [effect_hook(effect, realistic_values(effect, rng, truth), truth)] if effect else []
    meas, _ = simulate_session(design, seed, PLAN, effects=hooks, truth=truth)
    return (*bump_poses(meas, rng, n_bumped), design)


def _inputs(meas, design, inst=INST) -> Inputs:
    return Inputs(meas, design, inst, "stated" if inst else "estimated", "simulated session")


@pytest.mark.parametrize("seed", range(400, 405))
def test_outliers_and_backlash_are_named_and_the_chain_ends_at_the_floor(design, seed):
    """Backlash hidden and three 0.5 mm outliers: the first verdict is ``backlash`` with the
    three outliers listed (set aside); ``diagnose --auto`` then reads ``outliers`` (backlash
    added, the rest at the floor) and, the outliers acknowledged, ``none`` — with the held-out
    RMS at the floor once both are handled (3σ of a correct model's: statcheck.floor_limit)."""
    meas, rows, design = _session(design, seed, "backlash")
    ids = sorted(int(i) for i in meas.pose_id[rows])
    chain = diagnose_chain(_inputs(meas, design), 42, auto=True)
    assert [d.verdict for d in chain] == ["backlash", "outliers", "none"], [
        (d.verdict, d.outlier_ids, d.notes[:1]) for d in chain
    ]
    for d in chain:
        assert sorted(d.outlier_ids) == ids
        assert len(d.problem.meas) == len(meas) - 3  # the fit and its folds are without them
        assert len(d.session_problem.meas) == len(meas)  # nothing deleted
    first, last = chain[0], chain[-1]
    assert any("poses are outliers" in n and "backlash" in n for n in first.notes)
    assert last.effects == ("offset", "backlash") and last.outliers_acknowledged
    assert last.fit.cv_rms_mm <= floor_limit(last)
    assert chain[1].fit.cv_rms_mm <= floor_limit(chain[1])
    out = first.to_dict()["outliers"]
    assert [o["pose_id"] for o in out] == ids
    assert all({"index", "step", "t", "chi2"} <= set(o) for o in out)
    assert all(o["chi2"] > first.outlier_threshold for o in out)


@pytest.mark.parametrize("seed", range(410, 415))
def test_outliers_alone_are_the_whole_story(design, seed):
    """Three outliers and no hidden effect: ``outliers`` and nothing else (then ``none`` once
    acknowledged); the held-out RMS without them is at the floor."""
    meas, rows, design = _session(design, seed)
    chain = diagnose_chain(_inputs(meas, design), 42, auto=True)
    assert [d.verdict for d in chain] == ["outliers", "none"]
    d = chain[0]
    assert sorted(d.outlier_ids) == sorted(int(i) for i in meas.pose_id[rows])
    assert d.effects == ("offset",)
    assert d.fit.cv_rms_mm <= floor_limit(d)
    assert any("whole story" in n for n in d.notes)
    # Nothing deleted: the residual table has every pose, the outliers marked and off by far
    # more than the floor; the residuals of the kept poses are the fit's own.
    table = list(csv.DictReader(io.StringIO(d.residual_table())))
    assert len(table) == 6 * len(meas)
    aside = [r for r in table if r["set_aside"] == "1"]
    assert len(aside) == 18 and {int(r["pose_id"]) for r in aside} == set(d.outlier_ids)
    assert max(abs(float(r["residual_um"])) / float(r["floor_um"]) for r in aside) > 10
    kept = np.setdiff1d(np.arange(len(meas)), rows)
    assert np.allclose(pose_residuals(d.session_problem, d.fit)[kept], d.fit.residuals, atol=1e-9)


def test_without_setting_them_aside_the_outliers_make_it_unexplained(design):
    """The problem this solves: the same session diagnosed with the outliers left in."""
    meas, _, design = _session(design, 400, "backlash")
    d = diagnose(meas, design, 42, instruments=INST, set_aside_outliers=False)
    assert d.verdict == "unexplained" and not d.outliers


def test_outliers_are_found_without_stated_noise(design):
    """Without an instruments file the pose χ² are judged against a robust noise level (the
    median pose), not the residual level the outliers inflate."""
    meas, rows, design = _session(design, 420)
    d = diagnose(meas, design, 42)
    assert d.verdict == "outliers"
    assert sorted(o.index for o in d.outliers) == rows.tolist()


@pytest.mark.slow
def test_no_false_alarm_on_clean_sessions(design):
    """Sessions without outliers (56 seeds, each hiding one catalogue effect at a realistic
    size or none; the noise stated, and for every other session also estimated): at most 5 %
    of the searches set a pose aside, and none of those makes ``outliers`` the verdict.

    Measured (benchmarks/diagnosis_rates.py's 400 sessions: 50 per effect and clean; see the
    report): no pose set aside except in backlash sessions, where a leg moved within the
    encoder noise of the backlash dead band before a pose, so its backlash state is ambiguous
    and one leg reads the whole play off (36–62 µm, χ² 80–160) — a real inconsistency, set
    aside and listed, but never a verdict (the model is at the floor with it)."""
    design = design.model_copy(update={"platform_mass_kg": 20.0})
    effects = (None, "gain", "backlash", "thermal", "compliance", "leadscrew", "drift")
    alarms, tests = [], 0
    for i, seed in enumerate(range(500, 556)):
        effect = effects[i % len(effects)]
        rng = np.random.default_rng(seed)
        truth = perturbed_truth(design, rng, PLAN)
        hooks = [effect_hook(effect, realistic_values(effect, rng, truth), truth)] if effect else []
        meas, _ = simulate_session(design, seed, PLAN, effects=hooks, truth=truth)
        for inst in (INST, None)[: 1 + i % 2]:
            sig = None if inst is None else NoiseSigmas.from_instruments(inst)
            problem = Problem.build(meas, design, sig)
            search = find_outliers(problem, ("offset",))
            tests += 1
            if search.outliers:
                alarms.append((seed, effect, inst is not None, search.pose_ids))
                d = diagnose(meas, design, 42, instruments=inst, problem=problem)
                assert d.verdict != "outliers", (seed, effect, d.notes[:1])
    assert tests == 84
    assert len(alarms) <= 0.05 * tests, alarms


def test_the_threshold_is_bonferroni_over_the_poses():
    from scipy import stats

    assert outlier_threshold(184) == pytest.approx(stats.chi2.isf(OUTLIER_ALPHA / 184, 6))
    assert 34.0 < outlier_threshold(184) < 35.0
    assert outlier_threshold(1000) > outlier_threshold(184)


def test_a_subset_keeps_the_motion_history_of_the_whole_session(design):
    """Setting poses aside must not change the direction each remaining leg last moved: the
    history-dependent bases are the whole session's, rows taken."""
    meas, _, design = _session(design, 430, n_bumped=0)
    full = Problem.build(meas, design, NoiseSigmas.from_instruments(INST))
    rows = np.setdiff1d(np.arange(len(meas)), [5, 6, 7, 50])
    sub = Subset.of(full, rows)
    assert np.array_equal(sub.basis("backlash"), full.basis("backlash")[rows])
    assert len(sub.meas) == len(rows) and sub.parent is full
    # Drift is reckoned from the session's middle even with its first and last poses set
    # aside: a model fitted on the rest predicts the whole session as it predicted the rest.
    rows = np.arange(1, len(meas) - 1)
    fit = fit_model(Subset.of(full, rows), ("offset", "drift", "backlash"), cross_validate=False)
    assert np.allclose(pose_residuals(full, fit)[rows], fit.residuals, atol=1e-9)
