"""The diagnosis on sessions with hidden effects: the verdict, the fall of the error once the
named effect is added, `none` on clean data, `unexplained` (and where) for a structured effect
outside the catalogue. The full rates over ≥ 50 sessions per case are measured by
benchmarks/diagnosis_rates.py; here a few seeded sessions per case."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from conftest import SHARED_EXAMPLE, instruments
from statcheck import floor_limit

from hexcal.app.cli import main
from hexcal.diagnosis import diagnose
from hexcal.diagnosis.scoring import (
    block_score,
    needed_resolution,
    orthonormal,
    projected_scores,
    whitened_columns,
)
from hexcal.effects.base import ParamSpec
from hexcal.estimate.effect_fit import Problem, fit_model
from hexcal.model.noise import NoiseSigmas
from hexcal.sim.foreign import local_dent
from hexcal.sim.inject import effect_hook, realistic_values
from hexcal.sim.session_sim import SessionPlan, perturbed_truth, simulate_session
from hexcal.sim.simulate import PoseRanges

INST = instruments()


def _session(design, seed, hooks_for=None):
    design = design.model_copy(update={"platform_mass_kg": 20.0})
    rng = np.random.default_rng(seed)
    plan = SessionPlan(temperature_rise_k=5.0)
    truth = perturbed_truth(design, rng, plan)
    hooks = hooks_for(rng, truth) if hooks_for else []
    meas, _ = simulate_session(design, seed, plan, effects=hooks, truth=truth)
    return meas, design


@pytest.mark.parametrize("name", ["gain", "backlash", "thermal", "compliance", "leadscrew"])
def test_hidden_effect_is_named_and_adding_it_brings_the_error_to_the_floor(design, name):
    meas, design = _session(
        design, 300, lambda rng, t: [effect_hook(name, realistic_values(name, rng, t), t)]
    )
    before = diagnose(meas, design, 42, instruments=INST)
    assert before.verdict == name, [(c.effect, c.delta_bic, c.explained) for c in before.candidates]
    after = diagnose(meas, design, 42, add=[name], instruments=INST, problem=before.problem)
    assert after.verdict == "none"
    assert after.fit.cv_rms_mm < before.fit.cv_rms_mm
    assert after.fit.cv_rms_mm <= floor_limit(after)


def test_clean_session_says_none(design):
    meas, design = _session(design, 301)
    d = diagnose(meas, design, 42, instruments=INST)
    assert d.verdict == "none" and not d.excess_significant
    assert d.where["summary"] == "residual at the noise floor everywhere"


def test_structured_effect_outside_the_catalogue_is_unexplained_and_located(design):
    home = np.array(design.home.position)
    meas, design = _session(design, 302, lambda rng, t: [local_dent(5, 0, 0.05, home)])
    d = diagnose(meas, design, 42, instruments=INST)
    assert d.verdict == "unexplained"
    assert d.where["worst_legs"][0] == "leg 5"
    assert "leg 5" in d.where["summary"]


def test_offset_error_found_under_model_36(design):
    meas, design = _session(design, 303)
    design = design.with_geometry(
        design.a, design.b, design.offsets
    )  # true offsets differ by ≤ 1 mm
    d = diagnose(meas, design, 36, instruments=INST)
    assert d.verdict == "offset"


@pytest.mark.parametrize("seed", [304, 300])
def test_absorbed_effect_is_refused_with_what_absorbs_it(design, seed):
    """Poses that barely change the legs' directions cannot separate an offset from the base
    points: the candidate is refused, naming the base points and the motion to record. (Seed
    300: the three largest coefficients are not the three largest shares.)"""
    design = design.model_copy(update={"platform_mass_kg": 20.0})
    plan = SessionPlan(
        n_type_i=0,
        n_type_ii=0,
        n_type_iii=0,
        n_free=120,
        ranges=PoseRanges(box_mm=(0.5, 0.5, 40.0), tilt_deg=0.05),
    )
    meas, _ = simulate_session(design, seed, plan)
    problem = Problem.build(meas, design, NoiseSigmas.from_instruments(INST))
    fit = fit_model(problem, (), cross_validate=False)
    from hexcal.diagnosis.diagnose import score_candidate

    c = score_candidate(problem, fit, "offset")
    assert not c.identifiable
    assert any(n.startswith("a") for n in c.absorbed_by)
    assert "change each leg's direction" in c.reason
    # The names are the three parameters whose columns carry most of the worst-absorbed
    # offset column (the score test's smallest principal angle): by numpy's least squares on
    # the fit's whitened Jacobian, each parameter's coefficient times its column's norm.
    from hexcal.diagnosis.score import score_columns
    from hexcal.diagnosis.scoring import whitened_columns

    jw, _, _ = fit.refinement.whitened()
    worst = int(np.argmin(score_columns(problem, fit, "offset").sines))
    col = whitened_columns(fit, problem.basis("offset"))[:, worst]
    coef, *_ = np.linalg.lstsq(jw, col, rcond=None)
    share = np.abs(coef) * np.linalg.norm(jw, axis=0)
    top = [fit.refinement.names[i] for i in np.argsort(-share)[:3]]
    assert c.absorbed_by == top


def test_nonphysical_value_is_flagged(design):
    """A 12 mm departure of an offset from its design value is outside the plausible ±10 mm
    (legs measured by hand are off by a few mm): the fit flags it with what it means and what
    to check — a flag, not a verdict."""
    meas, design = _session(design, 305)
    off = design.offsets.copy()
    off[1] -= 12.0  # the design file is 12 mm off on leg 2
    problem = Problem.build(
        meas, design.with_geometry(design.a, design.b, off), NoiseSigmas.from_instruments(INST)
    )
    fit = fit_model(problem, ("offset",), cross_validate=False)
    assert [p.name for p in fit.nonphysical()] == ["offset2"]
    assert any(
        n.startswith("offset2 = ")
        and "outside its plausible range" in n
        and re.search(r"leg 2 is 1[1-3](\.\d)? mm longer at zero reading", n)
        and "set plausible in robot.json" in n
        for n in fit.notes
    ), fit.notes


def test_missing_data_makes_an_effect_unavailable(design):
    # (compliance no longer needs the mass: without it, c·m is fitted)
    meas, design = _session(design, 306)
    no_pitch = design.model_copy(update={"leadscrew_pitch_mm": None})
    d = diagnose(meas, no_pitch, 42, instruments=INST)
    c = d.candidate("leadscrew")
    assert not c.available and "leadscrew_pitch_mm" in c.reason


@pytest.mark.skipif(not (SHARED_EXAMPLE / "truth.json").exists(), reason="../shared is absent")
@pytest.mark.parametrize("model, verdict", [(36, "offset"), (42, "none")])
def test_shared_example(capsys, model, verdict):
    rc = main(
        [
            "diagnose",
            str(SHARED_EXAMPLE / "measurements.csv"),
            "--robot",
            str(SHARED_EXAMPLE / "robot.json"),
            "--instruments",
            str(SHARED_EXAMPLE / "instruments.json"),
            "--model",
            str(model),
            "--json",
        ]
    )
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    for key in (
        "model",
        "effects",
        "rms_mm",
        "cv_rms_mm",
        "noise_floor_mm",
        "verdict",
        "candidates",
        "where",
    ):
        assert key in out
    assert out["verdict"] == verdict
    for c in out["candidates"]:
        assert {"effect", "cv_rms_mm_after", "delta_bic", "identifiable"} <= set(c)


def test_effect_that_only_nibbles_is_not_the_answer(design):
    """A dent along z correlates with leg length, so a gain absorbs part of it; but adding gain
    leaves a significant excess that no catalogue effect explains: `unexplained`, not `gain`."""
    home = np.array(design.home.position)
    meas, design = _session(design, 307, lambda rng, t: [local_dent(1, 2, 0.05, home)])
    d = diagnose(meas, design, 42, instruments=INST)
    assert d.verdict == "unexplained"
    assert d.where["worst_legs"][0] == "leg 1"
    g = d.candidate("gain")
    assert g is not None and not g.closes


def test_two_hidden_effects_are_named_one_after_the_other(design):
    def hooks(rng, t):
        return [effect_hook(e, realistic_values(e, rng, t), t) for e in ("gain", "backlash")]

    meas, design = _session(design, 308, hooks)
    first = diagnose(meas, design, 42, instruments=INST)
    assert first.verdict in ("gain", "backlash")
    second = diagnose(
        meas, design, 42, add=[first.verdict], instruments=INST, problem=first.problem
    )
    assert {first.verdict, second.verdict} == {"gain", "backlash"}
    third = diagnose(
        meas, design, 42, add=["gain", "backlash"], instruments=INST, problem=first.problem
    )
    assert third.verdict == "none"


def test_residual_table_has_every_pose_and_leg(backlash_diagnoses, tmp_path):
    import csv

    before, _, meas, _ = backlash_diagnoses
    path = tmp_path / "res.csv"
    path.write_text(before.residual_table())
    rows = list(csv.DictReader(path.open()))
    assert len(rows) == 6 * len(meas)
    r = rows[7]
    assert float(r["measured_mm"]) - float(r["predicted_mm"]) == pytest.approx(
        float(r["residual_um"]) / 1000, abs=1e-6
    )


def _rss(a: np.ndarray, r: np.ndarray) -> float:
    """The least-squares residual sum of squares of ``r`` on the columns of ``a`` (numpy's)."""
    x = np.linalg.lstsq(a, r, rcond=None)[0]
    return float(np.sum((r - a @ x) ** 2))


def test_orthonormal_spans_the_columns_and_drops_only_dependent_ones():
    """Against numpy: as many columns as ``matrix_rank`` (SVD) counts, orthonormal, spanning
    the columns — at any overall scale (1e-12 mm), with columns 8 decades apart in size, and
    with one column a combination of two others (dropped)."""
    rng = np.random.default_rng(0)
    a = rng.normal(size=(60, 5))
    dependent = np.column_stack([a, a[:, 0] + 2 * a[:, 1]])
    cases = [a, 1e-12 * a, a * np.logspace(4, -4, 5), dependent]
    for m in cases:
        q = orthonormal(m)
        assert q.shape == (60, np.linalg.matrix_rank(m))
        np.testing.assert_allclose(q.T @ q, np.eye(q.shape[1]), atol=1e-12)
        np.testing.assert_allclose(q @ (q.T @ m), m, atol=1e-9 * np.abs(m).max())


def test_a_basis_scores_the_chi2_numpys_least_squares_removes_with_it(design):
    """At a fitted Model 42 on a gain session, the χ² each gain column removes alone, and the
    block removes together, is numpy's drop in the residual sum of squares when the column (or
    block) is added to the fit's whitened Jacobian — at any column scale; a column the
    Jacobian absorbs removes nothing. Rounding only: to 1e-6 of the χ²."""
    meas, design = _session(
        design, 303, lambda rng, t: [effect_hook("gain", realistic_values("gain", rng, t), t)]
    )
    problem = Problem.build(meas, design, NoiseSigmas.from_instruments(INST))
    fit = fit_model(problem, ("offset",))
    jw, rw, _ = fit.refinement.whitened()
    chi2 = float(rw @ rw)
    gain = whitened_columns(fit, problem.basis("gain"))
    absorbed = jw @ np.random.default_rng(1).normal(size=jw.shape[1])
    cols = np.column_stack([gain, 1e-6 * gain[:, 0], absorbed])
    base = _rss(jw, rw)
    want = [base - _rss(np.column_stack([jw, c]), rw) for c in cols.T]
    got = projected_scores(fit, cols)
    np.testing.assert_allclose(got, want, atol=1e-6 * chi2)
    assert got[-1] == 0.0 and got[:6].max() > 1e3 * 1e-6 * chi2
    block = np.column_stack([gain, gain[:, 0] + gain[:, 1]])  # one column dependent
    assert block_score(fit, block) == pytest.approx(
        base - _rss(np.column_stack([jw, gain]), rw), abs=1e-6 * chi2
    )


def test_a_parameter_without_its_own_resolution_must_resolve_a_tenth_of_its_half_width():
    """ParamSpec's documented default: a tenth of the plausible half-width (a fraction, so a
    parameter known no better than its prior range is never separable); its own resolution
    otherwise."""
    specs = [
        ParamSpec("x.a", "mm", (-0.4, 0.6)),
        ParamSpec("x.b", "ppm", (0.0, 30.0)),
        ParamSpec("x.c", "mm", (-1.0, 1.0), resolution=0.3),
    ]
    np.testing.assert_allclose(needed_resolution(specs), [0.05, 1.5, 0.3], rtol=1e-12)
