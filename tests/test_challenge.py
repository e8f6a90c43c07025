"""A catalogue verdict challenged by the explorer (hexcal.diagnosis.challenge): a look-alike
outside the catalogue that predicts held-out poses better takes the verdict; the catalogue's
own effects keep theirs (their rates: benchmarks/diagnosis_rates.py)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import instruments

from hexcal.diagnosis import diagnose
from hexcal.diagnosis.challenge import CHALLENGE_Z, challenge
from hexcal.diagnosis.verdict import judge
from hexcal.sim import verdict_cases as vc
from hexcal.sim.inject import effect_hook, realistic_values
from hexcal.sim.session_sim import SessionPlan, perturbed_truth, simulate_session


def test_cross_talk_that_gain_closes_is_named_by_the_other_legs_stroke():
    """Two legs reading a third leg's stroke: the catalogue alone names `gain` (it brings the
    residual near the floor on these poses); the other leg's stroke predicts the held-out
    poses better, pose by pose, and takes the verdict."""
    c = vc.foreign("cross-talk", 8)
    d = diagnose(c.meas, c.design, 42, instruments=c.instruments)
    # Without the challenge the catalogue's judgement is gain.
    alone = judge(d.problem, d.fit.effects, d.problem.sigmas, [], fit=d.fit)
    assert alone.verdict == "gain"
    assert d.verdict == "unexplained"
    assert d.alike == []  # gain's look-alikes went with it: nothing named to plan against
    assert d.exploration is not None and d.exploration.lead is not None
    assert d.exploration.lead.covariate.name.startswith("stroke_leg")
    gain = d.candidate("gain")
    assert gain is not None and gain.refit is not None
    said = [n for n in d.notes if "gain is a look-alike here" in n]
    assert said, d.notes
    found = challenge(d.problem, d.fit, gain, d.noise_level, d.noise_level)
    assert found is not None and found.overturns and found.z > CHALLENGE_Z
    # The lead predicts held-out poses better than gain does, on the same poses.
    lead = d.exploration.lead
    assert lead.cv_rms_after_mm < gain.refit.cv_rms_mm


@pytest.mark.parametrize("name", ["gain", "compliance"])
def test_a_catalogue_effect_stands_against_the_explorer(design, name):
    """A hidden gain or compliance: the explorer's best shape (a line in each leg's stroke
    is gain itself) does not predict held-out poses better; the verdict stands, and the
    comparison says nothing where the two are one model."""
    design = design.model_copy(update={"platform_mass_kg": 20.0})
    rng = np.random.default_rng(301)
    plan = SessionPlan(temperature_rise_k=5.0)
    truth = perturbed_truth(design, rng, plan)
    hooks = [effect_hook(name, realistic_values(name, rng, truth), truth)]
    meas, _ = simulate_session(design, 301, plan, effects=hooks, truth=truth)
    d = diagnose(meas, design, 42, instruments=instruments())
    assert d.verdict == name
    named = d.candidate(name)
    assert named is not None
    found = challenge(d.problem, d.fit, named, d.noise_level, d.noise_level)
    assert found is not None and not found.overturns
    assert not any("look-alike here" in n for n in d.notes)


def test_two_fits_are_apart_beyond_the_margin_and_the_parameters_one_takes_up_of_the_noise():
    """fit_apart: the χ² between two fits' residuals (whitened) against 10 plus their
    parameter counts' difference; the same residuals are one model, whatever the counts."""
    from types import SimpleNamespace

    from hexcal.diagnosis.selection import ALIKE_DCHI2, fit_apart

    rng = np.random.default_rng(0)
    m = 50
    chol = np.tile(np.eye(6) * 0.5, (m, 1, 1))  # σ 0.5 on every leg
    base = rng.normal(0, 0.5, (m, 6))
    step = np.zeros((m, 6))
    step[0, 0] = 0.5  # one σ on one reading: χ² 1 between the fits

    def fit(r, p):
        return SimpleNamespace(residuals=r, n_params=p)

    assert not fit_apart(fit(base, 84), fit(base, 84), chol)
    for p_b, chi2 in ((84, ALIKE_DCHI2 + 1), (90, ALIKE_DCHI2 + 5)):
        d = np.sqrt(chi2) * step
        assert fit_apart(fit(base, 84), fit(base + d, p_b), chol) == (p_b == 84), (p_b, chi2)
    d = np.sqrt(ALIKE_DCHI2 + 7) * step
    assert fit_apart(fit(base, 84), fit(base + d, 90), chol)
