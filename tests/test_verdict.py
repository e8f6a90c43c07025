"""The verdict when several effects hide at once, and when none does: the rules of
:mod:`hexcal.diagnosis.verdict` on constructed candidates, ``--auto`` through three hidden
catalogue effects, and one story from the outlier search and ``where``. The rates over 50
sessions per case are measured by benchmarks/diagnosis_rates.py; here seeded sessions."""

from __future__ import annotations

import re
from itertools import pairwise
from types import SimpleNamespace

import numpy as np
import pytest
from statcheck import floor_limit

from hexcal.app.workflow import Inputs, diagnose_chain
from hexcal.diagnosis import diagnose
from hexcal.diagnosis.scoring import Candidate
from hexcal.diagnosis.selection import (
    ALIKE_DCHI2,
    BIC_STRONG,
    CLEAR,
    HELDOUT_Z,
    MOST,
)
from hexcal.diagnosis.selection import alike as _alike
from hexcal.diagnosis.selection import indistinct as _indistinct
from hexcal.diagnosis.selection import wins as _wins
from hexcal.diagnosis.text import diagnosis_text
from hexcal.diagnosis.verdict import (
    _catalogue_closes,
    _named_notes,
    _note_heldout_refusals,
    judge,
    scaled,
)
from hexcal.estimate.effect_fit import Problem
from hexcal.model.noise import NoiseSigmas
from hexcal.sim import verdict_cases as vc
from hexcal.sim.inject import effect_hook, realistic_values, zero_jump_hook
from hexcal.sim.robots import left_hand
from hexcal.sim.session_sim import SessionPlan, bump_poses, perturbed_truth, simulate_session
from hexcal.sim.simulate import NoiseModel


def _cand(
    name="gain",
    dbic=-50.0,
    explained=0.6,
    z=5.0,
    closes=False,
    chain=False,
    chi2=1000.0,
    residuals=None,
):
    c = Candidate(name, 100.0, True, True)
    c.refit = SimpleNamespace(chi2=chi2, cv_rms_mm=0.011, residuals=residuals)  # type: ignore[assignment]
    c.delta_bic, c.explained, c.heldout_z, c.closes, c.chain = dbic, explained, z, closes, chain
    return c


def test_at_the_floor_an_effect_is_named_only_when_it_predicts_held_out_poses_better():
    strong = BIC_STRONG - 5
    assert _wins(_cand(dbic=strong, z=HELDOUT_Z + 0.5), excess=False)
    assert not _wins(_cand(dbic=strong, z=HELDOUT_Z - 0.5), excess=False)
    assert not _wins(_cand(dbic=BIC_STRONG + 5, z=10.0), excess=False)


def test_above_the_floor_an_effect_closes_the_excess_or_leads_a_chain_the_catalogue_closes():
    assert _wins(_cand(explained=MOST + 0.1, closes=True, z=0.0), excess=True)
    assert not _wins(_cand(explained=MOST - 0.1, closes=True), excess=True)
    # Several effects at once: a clear share, a held-out gain, and the rest within the catalogue.
    assert _wins(_cand(explained=CLEAR + 0.05, chain=True), excess=True)
    assert not _wins(_cand(explained=CLEAR + 0.05, chain=False), excess=True)
    assert not _wins(_cand(explained=CLEAR - 0.05, chain=True), excess=True)
    assert not _wins(_cand(explained=0.9, chain=True, z=HELDOUT_Z - 0.5), excess=True)


def test_effects_that_fit_alike_are_named_together_whatever_their_parameter_count():
    """Alike: χ² within ALIKE_DCHI2, or poses' χ² whose difference is inside its own noise
    (Vuong's z < HELDOUT_Z), or fitting better than the best while its parameter count ranks it
    behind — here built from residuals whose per-pose χ² differ by a known mean and spread, so
    that z is known (z = mean/sd·√M). Two that both close the excess are alike only when the
    poses do not decide between them by the same test."""
    rng = np.random.default_rng(0)
    m = 400
    base = 3.0 * rng.normal(size=(m, 6))  # χ² per pose ≈ 54: a shift of ±3 keeps it positive

    def with_pose_chi2_shift(z_target: float) -> np.ndarray:
        # Scale each pose's residual so its χ² moves by d_m with mean/sd·√M = z_target.
        d = rng.normal(size=m)
        d = (d - d.mean()) / d.std(ddof=1) + z_target / np.sqrt(m)
        chi = np.sum(base**2, axis=1)
        return base * np.sqrt((chi + d) / chi)[:, None]

    eye = lambda: np.broadcast_to(np.eye(6), (m, 6, 6))  # noqa: E731
    best = _cand("thermal", dbic=-60, chi2=1000.0, residuals=base)
    near = _cand("gain", dbic=-30, chi2=1000.0 - 0.5 * ALIKE_DCHI2)  # more parameters
    far = _cand("drift", dbic=-55, chi2=1000.0 + 3 * ALIKE_DCHI2, residuals=with_pose_chi2_shift(6))
    inside = _cand(
        "backlash", dbic=-45, chi2=1000.0 + 3 * ALIKE_DCHI2, residuals=with_pose_chi2_shift(1)
    )
    # Fits decisively better, ranked behind by its parameters' cost only: not beaten.
    better = _cand(
        "ujoint", dbic=-50, chi2=1000.0 - 3 * ALIKE_DCHI2, residuals=with_pose_chi2_shift(-6)
    )
    weak = _cand("leadscrew", dbic=BIC_STRONG + 1, chi2=1000.0)
    unrefitted = Candidate("balljoint", 5.0, True, True)
    found = _alike(eye, best, [best, near, far, inside, better, weak, unrefitted], 1.0)
    assert found == ["gain", "backlash", "ujoint"]
    # Above the floor, two effects that each bring the residual to it: named together when
    # the poses cannot tell them apart, not when Vuong's test decides (z 6 against 1).
    best.closes = True
    kw = dict(chi2=1000.0 + 3 * ALIKE_DCHI2, explained=MOST + 0.1, closes=True)
    close_inside = _cand("compliance", dbic=-20, residuals=with_pose_chi2_shift(1), **kw)
    close_decided = _cand("drift", dbic=-20, residuals=with_pose_chi2_shift(6), **kw)
    assert _alike(eye, best, [best, close_inside, close_decided], 1.0) == ["compliance"]
    assert _indistinct(ALIKE_DCHI2 - 1, 5.0) and _indistinct(3 * ALIKE_DCHI2, HELDOUT_Z - 0.1)
    assert _indistinct(-3 * ALIKE_DCHI2, -5.0)
    assert not _indistinct(3 * ALIKE_DCHI2, HELDOUT_Z + 0.1)


@pytest.mark.parametrize("seed", [31, 32])
def test_three_hidden_effects_are_named_in_turn_and_auto_reaches_the_floor(seed):
    c = vc.three_effects(seed)
    chain = diagnose_chain(Inputs(c.meas, c.design, c.instruments, "stated", "three"), auto=True)
    verdicts = [str(d.verdict) for d in chain]
    assert verdicts[-1] == "none", verdicts
    assert set(verdicts[:-1]) == set(vc.THREE), verdicts
    last = chain[-1]
    assert last.fit.cv_rms_mm <= floor_limit(last)
    # A note's figures are the fits': where two effects fit alike (seed 31: thermal and drift),
    # the named one's held-out RMS is the next step's, refitted with it.
    quoted = []
    for d, after in pairwise(chain):
        for n in d.notes:
            m = re.search(rf"{d.verdict}: χ² [\d.]+, ΔBIC -?\d+, held-out ([\d.]+) µm", n)
            if m:
                quoted.append((float(m[1]), 1000 * after.fit.cv_rms_mm))
    assert all(q == pytest.approx(fit, abs=0.006) for q, fit in quoted), quoted
    assert len(quoted) == (seed == 31), [d.notes for d in chain]


def test_outliers_and_where_tell_one_story_when_the_noise_is_understated():
    """Noise 2× the stated one and three 0.5 mm outliers: the outliers are set aside, judged
    against the session's own level (the median pose), and ``where`` names them first and says
    the rest is spread evenly — never "at the noise floor everywhere" at χ²/dof 4."""
    c = vc.noise_understated(33)
    meas, rows = bump_poses(c.meas, np.random.default_rng(33), 3, 0.5)
    d = diagnose(meas, c.design, 42, instruments=c.instruments)
    assert sorted(d.outlier_ids) == sorted(int(i) for i in meas.pose_id[rows])
    assert d.verdict == "noise_understated"
    summary = d.where["summary"]
    assert summary.startswith("3 poses set aside as outliers")
    assert "the rest: spread evenly" in summary
    assert "at the noise floor everywhere" not in summary
    text = diagnosis_text(d, "the test session")
    assert "verdict: noise_understated" in text and "too low" in text


def test_the_json_carries_the_new_verdicts_fields(backlash_diagnoses):
    before, _, _, _ = backlash_diagnoses
    out = before.to_dict()
    assert out["verdict"] == "backlash"
    assert {"alike", "changes", "explore", "noise_factor"} <= set(out)
    assert out["explore"] is None and out["noise_factor"] is None
    assert isinstance(out["alike"], list) and isinstance(out["changes"], list)
    for cand in out["candidates"]:
        assert "heldout_z" in cand


def _estimated_noise_judgement(noise, hidden=(), seed=5, notes=None):
    """Judge a Left Hand session simulated with ``noise`` (and the effects ``hidden`` at their
    realistic size) without an instruments file, the floor then estimated from the residual."""
    design = left_hand().model_copy(update={"platform_mass_kg": 20.0})
    rng = np.random.default_rng(90_000 + seed)
    plan = SessionPlan(temperature_rise_k=5.0, noise=noise)
    truth = perturbed_truth(design, rng, plan)
    hidden = (hidden,) if isinstance(hidden, str) else hidden
    hooks = [effect_hook(h, realistic_values(h, rng, truth), truth) for h in hidden]
    meas, _ = simulate_session(design, seed, plan, effects=hooks, truth=truth)
    notes = [] if notes is None else notes
    return judge(Problem.build(meas, design, None), ("offset",), None, notes)


def test_an_estimated_noise_level_twice_the_typical_one_leaves_a_clean_session_at_the_floor():
    """Tracker and encoders twice as noisy as the typical instruments the estimate is relative
    to (DEFAULT_SIGMAS), nothing hidden, no instruments file: the level s² is the simulated
    2² = 4 and the fit's χ² over the floor it sets is 1. σ of s² is s²·√(2/dof) (the χ²
    distribution over dof ≈ 1060 rows), σ of χ²/dof √(2/dof); the band is 4 σ."""
    j = _estimated_noise_judgement(NoiseModel(0.02, 0.004, 0.004))
    dof = j.fit.dof
    assert j.s2 == pytest.approx(4.0, abs=4 * 4.0 * np.sqrt(2 / dof))
    assert j.chi2_per_dof == pytest.approx(1.0, abs=4 * np.sqrt(2 / dof))
    assert not j.excess and j.verdict == "none"


def test_an_effect_hidden_under_an_estimated_noise_level_explains_all_of_the_excess():
    """Gain hidden at its realistic size under noise twice the typical one, no instruments
    file: the excess over the estimated floor is the gain's, so the share it explains is 1
    within 4 σ, σ = √(2·dof)·s² / (χ² − dof·s²) (the refit's χ² spread over that excess), and
    its refit alone is back at the floor (s² ≈ 4 ≠ 1: the refit's χ² is taken over dof·s²)."""
    j = _estimated_noise_judgement(NoiseModel(0.02, 0.004, 0.004), hidden="gain")
    assert j.excess and j.verdict == "gain"
    gain = next(c for c in j.candidates if c.effect == "gain")
    assert gain.closes and gain.with_effect == ""
    excess = j.fit.chi2 - j.fit.dof * 4.0  # over the simulated level
    assert gain.explained == pytest.approx(1.0, abs=4 * np.sqrt(2 * j.fit.dof) * 4.0 / excess)


def test_an_estimated_floor_above_the_best_held_out_residual_comes_down_to_it():
    """Encoder noise only (10 µm; the tracker's 20× below typical): the typical mix the level
    is estimated in turns it into a floor above what any model leaves on held-out poses, so
    the floor is capped there, and then lies within 4 σ of the simulated 10 µm, σ = 10 µm /
    √(2·6M) (the RMS of 6M residuals), beside the cross-validation's p/n inflation."""
    j = _estimated_noise_judgement(NoiseModel(0.0005, 0.0001, 0.01))
    heldout = [j.fit.cv_rms_mm] + [c.refit.cv_rms_mm for c in j.candidates if c.refit]
    rms = float(np.sqrt(np.mean(j.floor**2)))
    assert j.floor_scale < 1.0
    assert rms <= min(heldout) * (1 + 1e-12)
    n = j.floor.size
    p = n - j.fit.dof
    assert rms == pytest.approx(0.01 * np.sqrt(1 + p / n), abs=4 * 0.01 / np.sqrt(2 * n))


def test_a_searched_zero_step_pays_in_delta_bic_for_its_time_as_well_as_its_size():
    """Two legs' zeros jump (leg 2 by +50 µm at pose 61, leg 5 by −50 µm at pose 121): both
    steps are found, and ΔBIC (stated noise: Δχ² + k·ln n over the n = 6M leg rows, by hand)
    counts each step twice — its size, fitted, and its time, searched — while an effect
    fitted without a search counts its parameters once."""
    design = left_hand().model_copy(update={"platform_mass_kg": 20.0})
    rng = np.random.default_rng(7)
    plan = SessionPlan(temperature_rise_k=5.0)
    truth = perturbed_truth(design, rng, plan)
    jumps = [zero_jump_hook(2, 60, 0.05), zero_jump_hook(5, 120, -0.05)]
    meas, _ = simulate_session(design, 7, plan, effects=jumps, truth=truth)
    d = diagnose(meas, design, 42, instruments=vc.INSTRUMENTS)
    assert d.verdict == "zero_step" and not d.outlier_ids
    assert sorted((c.leg, c.pose_id) for c in d.changes) == [(2, 61), (5, 121)]
    ln_n = np.log(6 * len(meas))
    refitted = [c for c in d.candidates if c.refit is not None]
    assert len(refitted) > 1
    for c in refitted:
        dchi2 = c.refit.chi2 - d.fit.chi2
        k = c.refit.n_params - d.fit.n_params
        searched = len(d.changes) if c.effect == "zero_step" else 0
        assert c.delta_bic == pytest.approx(dchi2 + (k + searched) * ln_n, abs=1e-6), c.effect


def test_two_effects_under_an_estimated_noise_level_name_the_first_and_what_it_leaves():
    """Backlash and gain hidden under noise twice the typical one, no instruments file (s² ≈
    4): backlash is named, its refit brings the residual to the floor only with gain (the
    remaining excess over (dof − gain's parameters)·s²), and the note says to add backlash and
    diagnose again. Both hidden effects are in the catalogue, so whatever any refit leaves, the
    other catalogue effects together explain: every refitted candidate leads a chain."""
    notes: list[str] = []
    j = _estimated_noise_judgement(
        NoiseModel(0.02, 0.004, 0.004), hidden=("gain", "backlash"), notes=notes
    )
    assert j.excess and j.verdict == "backlash"
    backlash = next(c for c in j.candidates if c.effect == "backlash")
    assert backlash.closes and backlash.with_effect == "gain"
    assert (
        "backlash leaves an excess that gain would explain: add backlash, then diagnose again"
        in notes
    )
    refitted = [c for c in j.candidates if c.refit is not None]
    assert len(refitted) == 3 and all(c.chain for c in refitted), [
        (c.effect, c.chain) for c in refitted
    ]


def test_an_effect_alone_in_the_catalogue_leaves_no_chain():
    """No other available, identifiable effect to explain what a refit leaves: no chain."""
    c = _cand("gain")
    other = Candidate("thermal", 10.0, False, True)  # not identifiable: it cannot help
    assert not _catalogue_closes(None, c, [c], 1.0, 1.2)  # type: ignore[arg-type]
    assert not _catalogue_closes(None, c, [c, other], 1.0, 1.2)  # type: ignore[arg-type]


def test_the_unexplained_note_lists_the_effects_that_help_with_their_refits_figures():
    """An effect outside the catalogue (a quadratic along the stroke, seed 40): unexplained.
    The note lists exactly the refitted effects with very strong evidence (ΔBIC below
    BIC_STRONG), each with the χ²/dof its refit leaves over the floor."""
    h = vc.foreign("stroke quadratic", 40)
    d = diagnose(h.meas, h.design, 42, instruments=h.instruments)
    assert d.verdict == "unexplained"
    refitted = [c for c in d.candidates if c.refit is not None]
    helpful = [c for c in refitted if c.delta_bic < BIC_STRONG]
    assert helpful and len(helpful) < len(refitted)  # both kinds, so the list is a choice
    note = next(n for n in d.notes if n.startswith("some effects help"))
    listed = re.findall(r"(\w+) \(explains (\d+) % of the excess, leaves χ²/dof ([\d.]+)\)", note)
    assert sorted(e for e, _, _ in listed) == sorted(c.effect for c in helpful)
    for effect, share, left in listed:
        c = next(c for c in helpful if c.effect == effect)
        assert int(share) == round(100 * c.explained)
        assert float(left) == pytest.approx(c.refit.chi2 / (c.refit.dof * d.noise_level), abs=0.006)


def test_at_the_floor_the_note_names_strong_effects_that_predict_no_better():
    """At the floor, an effect with very strong in-sample evidence but a held-out gain below
    HELDOUT_Z is named in the note, with its figures; one that predicts better, or with weak
    evidence, is not."""
    refused = _cand("gain", dbic=BIC_STRONG - 30, z=HELDOUT_Z - 1.5)
    better = _cand("thermal", dbic=BIC_STRONG - 30, z=HELDOUT_Z + 1.0)
    weak = _cand("drift", dbic=BIC_STRONG + 1, z=0.0)
    notes: list[str] = []
    _note_heldout_refusals([refused, better, weak], notes)
    assert len(notes) == 1
    gain = f"gain (ΔBIC {BIC_STRONG - 30:.0f}, held-out gain {HELDOUT_Z - 1.5:.1f} σ)"
    assert notes[0].startswith(f"at the noise floor, {gain} would fit better")
    assert "thermal" not in notes[0] and "drift" not in notes[0]
    notes.clear()
    _note_heldout_refusals([better, weak], notes)
    assert notes == []


def test_the_several_effects_note_quotes_the_share_and_the_held_out_rms():
    """A named effect that leads a chain without closing the excess: the note quotes the share
    it explains (%) and the held-out RMS before and after it (µm)."""
    best = _cand("gain", explained=0.62, chain=True)  # refit's held-out RMS 0.011 mm
    fit = SimpleNamespace(cv_rms_mm=0.0145)
    (note,) = _named_notes(best, [], fit, [best], 1.0)  # type: ignore[arg-type]
    assert note.startswith(
        "gain explains 62 % of the excess and predicts held-out poses better (held-out RMS "
        "14.50 → 11.00 µm), but leaves an excess that several other catalogue effects"
    )


def test_a_noise_scaled_is_each_of_its_sigmas_times_the_factor():
    s = scaled(NoiseSigmas(0.02, 0.004, 0.003), 2.5)
    assert (s.position_mm, s.orientation_rad, s.reading_mm) == pytest.approx((0.05, 0.01, 0.0075))
