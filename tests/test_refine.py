"""The weighted refinement: exact on clean data, intervals that hold their stated coverage, and
parameters the data cannot separate reported as such."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from hexcal.estimate.calibrate import calibrate
from hexcal.estimate.layout import ParameterLayout
from hexcal.estimate.refine import refine
from hexcal.model.noise import NoiseSigmas
from hexcal.sim.session_sim import SessionPlan, simulate_session
from hexcal.sim.simulate import NoiseModel, PoseRanges, Simulator

SIG = NoiseSigmas(0.01, np.deg2rad(0.002), 0.002)
SMALL = SessionPlan(n_type_i=0, n_type_ii=6, n_type_iii=6, n_free=30)
MODEL42 = ParameterLayout.for_model(42)


def _truth_vector(t):
    return MODEL42.pack(t.a, t.b, t.offsets)


def test_noise_free_refinement_is_exact(design):
    meas, truth = simulate_session(design, 11, SessionPlan(noise=NoiseModel(), resolution=None))
    P, R = meas.position, meas.rotations.as_matrix()
    rng = np.random.default_rng(0)
    ref = refine(
        P,
        R,
        meas.readings,
        truth.a + rng.normal(0, 0.5, (6, 3)),
        truth.b + rng.normal(0, 0.5, (6, 3)),
        truth.offsets + 0.5,
        True,
        SIG,
    )
    assert np.max(np.abs(ref.x - _truth_vector(truth))) < 1e-9 * 200


@pytest.mark.slow
@pytest.mark.parametrize("known", [True, False])
def test_intervals_have_their_coverage(design, known):
    """Over 80 random sessions the Mahalanobis distance of the error follows χ²(42) and the 95 %
    intervals cover the truth 95 % of the time, within Monte-Carlo error.

    With the noise stated, the reported covariance is widened by max(1, χ²/dof) on purpose (an
    under-fitting model must not narrow the intervals), which shifts the distance below χ²(42)
    by a few percent; the distance is taken with the covariance before that widening, which is
    the one the χ² law is about."""
    d2, inside = [], []
    inst = None
    if known:
        from hexcal.model.instruments import EncoderNoise, Instruments, TrackerNoise

        inst = Instruments(
            tracker=TrackerNoise(position_sigma_mm=0.01, orientation_sigma_deg=0.002),
            encoders=EncoderNoise(reading_sigma_mm=0.002),
        )
    for seed in range(80):
        meas, truth = simulate_session(design, 1000 + seed, SMALL)
        ref = calibrate(meas, design, 42, instruments=inst).refinement
        err = ref.x - _truth_vector(truth)
        widened = max(1.0, ref.chi2 / ref.dof) if known else 1.0
        d2.append(widened * (err @ np.linalg.solve(ref.cov, err)))
        inside.append(np.abs(err) <= ref.ci95)
    # χ²(42): a Kolmogorov-Smirnov test at the 0.1 % level.
    assert stats.kstest(d2, stats.chi2(42).cdf).pvalue > 1e-3, np.mean(d2)
    cover = np.mean(inside)
    assert abs(cover - 0.95) < 4 * np.sqrt(0.95 * 0.05 / 80), cover


def test_refined_beats_linear(design):
    """The refinement uses every pose of every leg: its error is well below the linear seed's."""
    lin_err, ref_err = [], []
    for seed in range(10):
        meas, truth = simulate_session(design, 2000 + seed, SMALL)
        cal = calibrate(meas, design, 42)
        t = _truth_vector(truth)
        lin = MODEL42.pack(cal.linear.a, cal.linear.b, cal.linear.offsets)
        lin_err.append(np.sqrt(np.mean((lin - t) ** 2)))
        ref_err.append(np.sqrt(np.mean((cal.refinement.x - t) ** 2)))
    assert np.median(ref_err) < 0.5 * np.median(lin_err)


def test_inseparable_parameters_are_reported(design):
    """Poses that barely change the legs' directions cannot separate a base point from its leg's
    offset along the leg: the fit says so instead of printing precise numbers."""
    sim = Simulator(
        design,
        ranges=PoseRanges(box_mm=(0.3, 0.3, 40.0), tilt_deg=0.05),
        noise=NoiseModel(0.01, 0.002, 0.002),
    )
    rng = np.random.default_rng(3)
    P, R = sim.free((200,), rng)
    Pm, Rm, rho = sim.measure(rng, P, R)
    ref = refine(Pm, Rm, rho, design.a, design.b, design.offsets, True, SIG)
    flagged = [n for n, s in zip(ref.names, ref.status, strict=False) if s != "ok"]
    assert any(n.startswith("offset") for n in flagged)
    assert any("not separable" in n or "not determined" in n for n in ref.notes)


def test_good_session_has_no_inseparable_parameters(design):
    meas, _ = simulate_session(design, 17, SessionPlan())
    ref = calibrate(meas, design, 42).refinement
    assert ref.status == ["ok"] * 42
    assert ref.noise_source == "estimated from the residual"
