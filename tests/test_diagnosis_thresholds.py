"""Each decision threshold of the diagnosis, guarded from its own formula: an effect just above
it is named, one just below is not, so that a threshold cannot move silently.

The thresholds, as their modules document them, written out here rather than imported:

- the excess: χ²/dof over the floor above 1 + 4·√(2/dof) (4 σ of χ²/dof), verdict.py;
- ΔBIC = Δχ² + Δp·ln n below −10 (very strong evidence, Kass & Raftery), verdict.py;
- an outlier: a pose's χ² over the noise level above χ²₆'s upper 10⁻³/M quantile (Bonferroni
  over the M poses), outliers.py;
- a change point: a step's score over the noise level above χ²₁'s upper 10⁻³/(6·S) quantile
  (Bonferroni over six legs and S = M − 5 splits, 3 poses each side at least), changepoint.py.

An effect's size is set exactly by scaling the noise the session states by s: every χ² and
score the decisions read is divided by s² while the fits stay the same (weighted least squares
does not move when all weights scale alike), so an effect measured once at s = 1 is placed at
a chosen multiple of its threshold. The margins are a few per cent: the decisions are
deterministic given the data, so this tests the thresholds, not the noise.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from hexcal.diagnosis import diagnose
from hexcal.diagnosis.changepoint import search
from hexcal.diagnosis.outliers import find_outliers
from hexcal.estimate.effect_fit import Problem, fit_model
from hexcal.model.instruments import EncoderNoise, Instruments, TrackerNoise
from hexcal.model.noise import NoiseSigmas
from hexcal.sim.inject import effect_hook, realistic_values, zero_jump_hook
from hexcal.sim.robots import left_hand
from hexcal.sim.session_sim import SessionPlan, bump_poses, perturbed_truth, simulate_session

#: The thresholds' constants as documented (module docstring).
EXCESS_Z, BIC_STRONG, OUTLIER_ALPHA, STEP_ALPHA, MIN_SIDE = 4.0, -10.0, 1e-3, 1e-3, 3
PLAN = SessionPlan(temperature_rise_k=5.0)
TRACKER_MM, TRACKER_DEG, ENCODER_MM = 0.01, 0.002, 0.002


def _stated(s: float = 1.0) -> Instruments:
    """The instruments' noise the simulator draws, stated ``s`` times."""
    return Instruments(
        tracker=TrackerNoise(
            position_sigma_mm=s * TRACKER_MM, orientation_sigma_deg=s * TRACKER_DEG
        ),
        encoders=EncoderNoise(reading_sigma_mm=s * ENCODER_MM),
    )


def _session(seed: int, effect: str | None = None, size: float = 1.0, hooks=()):
    # The dead band fixed at the stated noise's (4·√2·σ): derived from a scaled noise, it
    # would change the backlash effect's column with s.
    design = left_hand().model_copy(
        update={"platform_mass_kg": 20.0, "backlash_deadband_mm": 4 * np.sqrt(2) * ENCODER_MM}
    )
    rng = np.random.default_rng(seed)
    truth = perturbed_truth(design, rng, PLAN)
    hooks = list(hooks)
    if effect:
        hooks.append(
            effect_hook(effect, size * np.asarray(realistic_values(effect, rng, truth)), truth)
        )
    meas, _ = simulate_session(design, seed, PLAN, effects=hooks, truth=truth)
    return meas, design


# -- the excess ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def clean():
    meas, design = _session(1201)
    d = diagnose(meas, design, 42, instruments=_stated())
    assert not d.outliers
    return meas, design, d.fit.chi2 / d.fit.dof, d.fit.dof


@pytest.mark.parametrize(("z", "named"), [(EXCESS_Z * 1.05, True), (EXCESS_Z * 0.95, False)])
def test_an_excess_just_above_4_sigma_of_chi2_is_significant_and_just_below_is_not(clean, z, named):
    """Nothing hidden; the stated noise scaled so that χ²/dof = 1 + z·√(2/dof), z 5 % above
    or below 4: above, the excess is significant (verdict not ``none``); below, it is not."""
    meas, design, r0, dof = clean
    target = 1.0 + z * np.sqrt(2.0 / dof)
    d = diagnose(meas, design, 42, instruments=_stated(np.sqrt(r0 / target)))
    assert d.fit.chi2 / d.fit.dof == pytest.approx(target, rel=1e-3)
    assert d.excess_significant is named
    assert (d.verdict != "none") is named, d.verdict


# -- ΔBIC --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def gain_hidden():
    """Gain hidden at 15 % of its realistic size: named at the stated noise, ΔBIC −85, held-out
    gain 5 σ (which the noise's scale does not change: a ratio of χ² sums), no excess."""
    meas, design = _session(3, "gain", 0.15)
    d = diagnose(meas, design, 42, instruments=_stated())
    (c,) = [c for c in d.candidates if c.effect == "gain"]
    assert d.verdict == "gain" and c.refit is not None
    n = d.fit.refinement.dof + len(d.fit.refinement.x)
    dchi2 = c.refit.chi2 - d.fit.chi2
    dp = c.refit.n_params - d.fit.n_params
    assert c.delta_bic == pytest.approx(dchi2 + dp * np.log(n), abs=1e-6)
    return meas, design, dchi2, dp * np.log(n)


@pytest.mark.parametrize(("dbic", "named"), [(BIC_STRONG - 1.0, True), (BIC_STRONG + 1.0, False)])
def test_an_effect_just_below_bic_minus_10_is_named_and_just_above_is_not(gain_hidden, dbic, named):
    """The stated noise scaled by s so that ΔBIC = Δχ²/s² + Δp·ln n lands 1 below or above −10
    (the residual at the floor, where a named effect needs ΔBIC < −10 and its held-out gain)."""
    meas, design, dchi2, penalty = gain_hidden
    s = np.sqrt(dchi2 / (dbic - penalty))
    d = diagnose(meas, design, 42, instruments=_stated(s))
    (c,) = [c for c in d.candidates if c.effect == "gain"]
    assert c.delta_bic == pytest.approx(dbic, abs=0.05)
    assert not d.excess_significant
    assert (d.verdict == "gain") is named, (d.verdict, c.delta_bic, c.heldout_z)


# -- outliers ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def bumped():
    """One pose's measured position displaced 0.1 mm: its χ² (set aside, at the fit without it)
    measured at the stated noise."""
    meas, design = _session(1301)
    meas, rows = bump_poses(meas, np.random.default_rng(1301), 1, 0.1)
    (row,) = rows
    problem = Problem.build(meas, design, NoiseSigmas.from_instruments(_stated()))
    search0 = find_outliers(problem, (), start=np.array([row]))
    assert [o.index for o in search0.outliers] == [row]
    threshold = stats.chi2.isf(OUTLIER_ALPHA / len(meas), 6)
    chi2 = search0.outliers[0].chi2 * search0.noise_level  # at the stated noise
    assert chi2 > 1.5 * threshold
    return meas, design, row, chi2, threshold


@pytest.mark.parametrize(("ratio", "named"), [(1.02, True), (0.98, False)])
def test_a_pose_just_beyond_the_outlier_limit_is_set_aside_and_just_inside_is_not(
    bumped, ratio, named
):
    """The pose's χ² placed 2 % above or below χ²₆ isf(10⁻³/M), by stating the noise s > 1.2
    times larger: the level is then the stated one, s² = 1 (the session's median pose is
    below it)."""
    meas, design, row, chi2, threshold = bumped
    s = np.sqrt(chi2 / (ratio * threshold))
    problem = Problem.build(meas, design, NoiseSigmas.from_instruments(_stated(s)))
    found = find_outliers(problem, (), start=np.array([row]))
    assert found.threshold == pytest.approx(threshold, rel=1e-9) and found.noise_level == 1.0
    assert ([o.index for o in found.outliers] == [row]) is named


# -- change points --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def jumped():
    """Leg 4 reads 30 µm longer from the middle pose on: its step's score at level 1."""
    meas0, _ = _session(1401)
    m = len(meas0)
    meas, design = _session(1401, hooks=[zero_jump_hook(4, m // 2, 0.03)])
    problem = Problem.build(meas, design, NoiseSigmas.from_instruments(_stated()))
    fit = fit_model(problem, ())
    change = search(problem, fit, 1.0)[0]  # the strongest; it leaks into other legs' residual
    assert change.leg == 4
    threshold = stats.chi2.isf(STEP_ALPHA / (6 * (m - 2 * MIN_SIDE + 1)), 1)
    assert change.chi2 > 1.5 * threshold
    return problem, fit, change.chi2, threshold


@pytest.mark.parametrize(("ratio", "named"), [(1.02, True), (0.98, False)])
def test_a_step_just_above_the_change_point_limit_is_located_and_just_below_is_not(
    jumped, ratio, named
):
    """The step's score over the noise level placed 2 % above or below χ²₁ isf(10⁻³/(6·S))."""
    problem, fit, score, threshold = jumped
    found = search(problem, fit, score / (ratio * threshold))
    assert bool(found) is named
    if named:
        assert found[0].leg == 4 and found[0].threshold == pytest.approx(threshold, rel=1e-9)
