"""Cross-validation folds refitted from the full fit, sharing its work, give each fold's own
fit: the refinement on the fold's training poses from the full fit (one covariance pass)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hexcal.estimate.calibrate import calibrate
from hexcal.estimate.effect_fit import Problem, fit_model
from hexcal.estimate.folds import fold_fits
from hexcal.estimate.layout import ParameterLayout
from hexcal.estimate.leg_rows import LegData
from hexcal.estimate.model_file import load_robot
from hexcal.estimate.refine import FitStalled, refine
from hexcal.io.measurements_csv import read_measurements
from hexcal.model.instruments import load_instruments
from hexcal.model.noise import NoiseSigmas

WALKTHROUGH = Path(__file__).resolve().parents[1] / "docs" / "walkthrough" / "session"


@pytest.fixture(scope="module")
def session():
    meas = read_measurements(WALKTHROUGH / "measurements.csv")
    design = load_robot(WALKTHROUGH / "robot.json")
    sig = NoiseSigmas.from_instruments(load_instruments(WALKTHROUGH / "instruments.json"))
    return meas, design, sig


@pytest.mark.parametrize("effects", [("offset",), ("offset", "backlash")])
def test_each_fold_is_its_own_fit(session, effects):
    """With and without an effect's columns, random and blocked folds: each fold's parameters
    are those of the refinement on its training poses, to 1e-9 mm."""
    meas, design, sig = session
    problem = Problem.build(meas, design, sig)
    fit = fit_model(problem, effects, cross_validate=False)
    assert fit.basis is not None
    x0 = fit.refinement.x
    lay = ParameterLayout.of_vector(x0, True)
    P, R, rho = meas.position, problem.R, meas.readings
    basis = fit.basis if fit.basis.shape[-1] else None
    m = len(meas)
    random = [np.sort(f) for f in np.array_split(np.random.default_rng(0).permutation(m), 5)]
    blocked = np.array_split(np.arange(m), 5)
    got = fold_fits(LegData.of(P, R, rho, design.offsets, basis), x0, lay, sig, [random, blocked])
    for part, xs in zip((random, blocked), got, strict=True):
        for test, x in zip(part, xs, strict=True):
            train = np.setdiff1d(np.arange(m), test)
            want = refine(
                P[train],
                R[train],
                rho[train],
                lay.a(x0),
                lay.b(x0),
                lay.offsets(x0),
                True,
                sig,
                basis=None if basis is None else basis[train],
                theta0=lay.effects(x0) if basis is not None else None,
                passes=1,
            )
            assert np.max(np.abs(x - want.x)) < 1e-9


def test_a_fold_that_cannot_converge_stops(session):
    meas, design, sig = session
    cal = calibrate(meas, design, 42, clamps=False)
    assert cal.refinement is not None
    x0 = cal.refinement.x
    lay = ParameterLayout(True)
    d = LegData.of(meas.position, meas.rotations.as_matrix(), meas.readings, design.offsets)
    part = np.array_split(np.arange(len(meas)), 5)
    with pytest.raises(FitStalled, match="cross-validation fold"):
        fold_fits(d, x0 + 0.5, lay, sig, [part], max_nfev=2)
