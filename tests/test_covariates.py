"""Where an unexplained residual points: the covariate explorer names the quantity an effect
outside the catalogue follows, with the share of the excess it explains; a noise understated
alike everywhere points nowhere; what the geometry absorbs is not named at all. The rates over
50 sessions per case are measured by benchmarks/diagnosis_rates.py; here seeded sessions."""

from __future__ import annotations

import numpy as np
import pytest

from hexcal.app.workflow import Inputs, diagnose_chain
from hexcal.diagnosis import diagnose
from hexcal.diagnosis.covariates import COVARIATES, Shape, hats, knots_of, shapes_for
from hexcal.sim import verdict_cases as vc


def _chain(c):
    return diagnose_chain(Inputs(c.meas, c.design, c.instruments, "stated", c.case), 42, auto=True)


@pytest.fixture(scope="module", params=list(vc.FOREIGN))
def foreign(request):
    """Each effect outside the catalogue, on one seeded session, through ``--auto``."""
    c = vc.foreign(request.param, 11)
    return c, _chain(c)


def test_the_explorer_names_the_covariate_an_effect_outside_the_catalogue_follows(foreign):
    c, chain = foreign
    last = chain[-1]
    assert last.verdict == "unexplained", [d.verdict for d in chain]
    lead = last.exploration.lead
    assert lead is not None and lead.covariate.name == c.covariate, last.exploration.summary()
    assert lead.share > 0.5
    assert lead.score > lead.threshold
    d = last.to_dict()
    assert d["explore"]["leads"][0]["covariate"] == c.covariate
    assert d["explore"]["leads"][0]["share_of_excess"] == pytest.approx(lead.share)


def test_the_shape_fits_the_physics(foreign):
    """A quadratic error is named as a parabola, play at the load's reversal as a step at the
    force's sign change, a dent as a piecewise-linear shape on few legs."""
    c, chain = foreign
    shape = chain[-1].exploration.lead.shape
    expected = {"stroke quadratic": "poly", "joint play": "sign", "stroke dent": "knots"}
    assert shape.kind == expected[c.case], shape.describe()
    if c.case == "stroke quadratic":
        assert shape.degree == 2
    if c.case == "stroke dent":
        assert len(shape.legs) <= 2


def test_a_noise_understated_points_nowhere_and_says_so():
    c = vc.noise_understated(12)
    d = diagnose(c.meas, c.design, 42, instruments=c.instruments)
    assert d.verdict == "noise_understated"
    assert abs(d.noise_factor / vc.NOISE_FACTOR - 1) < 0.2
    assert d.exploration is not None and not d.exploration.leads
    assert d.where["even"] and "spread evenly" in d.where["summary"]
    assert not d.outliers
    assert d.to_dict()["noise_factor"] == pytest.approx(d.noise_factor)
    assert any("stated noise looks about 2.0× too low" in n for n in d.notes), d.notes


@pytest.mark.parametrize("case", vc.ABSORBED)
def test_what_the_geometry_absorbs_is_not_named(case):
    """A tracker scale error of 30–100 ppm and a sag ∝ sin²θ are taken up by the joint
    positions: the session is at the floor and no effect is named."""
    c = vc.absorbed(case, 13)
    d = diagnose(c.meas, c.design, 42, instruments=c.instruments)
    assert d.verdict == "none", [(x.effect, x.delta_bic, x.heldout_z) for x in d.candidates]
    assert d.where["summary"] == "residual at the noise floor everywhere"


def test_knots_are_dense_where_the_poses_are_yet_never_on_top_of_each_other():
    rng = np.random.default_rng(0)
    u = np.concatenate([np.full(60, 50.0), rng.uniform(0, 100, 60)])  # a clamped leg repeats
    values = np.repeat(u[:, None], 6, axis=1)
    k = knots_of(values, 9)
    assert k.shape == (6, 9)
    gaps = np.diff(k, axis=1)
    assert (gaps >= 0.5 * np.ptp(u) / 8 - 1e-9).all()


def test_the_hats_and_the_offset_span_every_piecewise_linear_shape():
    knots = np.array([0.0, 1.0, 3.0, 6.0])
    u = np.linspace(-1, 7, 50)
    h = hats(u, knots)
    assert h.shape == (50, 3)
    first = np.interp(np.clip(u, 0, 6), knots, [1.0, 0, 0, 0])
    np.testing.assert_allclose(h.sum(axis=1) + first, 1.0)


def test_every_covariate_has_its_shapes():
    rng = np.random.default_rng(1)
    values = rng.normal(10.0, 20.0, (40, 6))  # crosses zero: the force's sign is tried
    for cov in COVARIATES:
        shapes = shapes_for(cov, values)
        kinds = {s.kind for s in shapes}
        if cov.discrete:
            assert kinds == {"sign"}
        else:
            assert {"poly", "knots"} <= kinds
            assert ("sign" in kinds) == cov.signed
        for s in shapes:
            b = s.basis(values)
            assert b.shape == (40, 6, 6 * s.per_leg)
    one = Shape("sign", legs=(3,))
    b = one.basis(values)
    assert b.shape == (40, 6, 1) and np.count_nonzero(b[:, [0, 1, 3, 4, 5]]) == 0
