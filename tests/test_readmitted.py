"""The explorer's "never worse" on the poses its file would keep (hexcal.diagnosis.readmitted).

A dent on one leg (``stroke dent``, seed 43): the model without it sets the dent's deepest
poses aside as outliers; a spline along the stroke, fitted on the rest, readmits them once
its file is loaded, and predicts them worse than no shape at all (held-out RMS 11.10 → 11.56
µm on the same 184 poses before this check). Such a lead must not be proposed.
"""

from __future__ import annotations

import importlib.util

import pytest

from hexcal.diagnosis import diagnose
from hexcal.diagnosis.effect_file import effect_name, write_effect_file
from hexcal.diagnosis.same_poses import before_on_after_poses
from hexcal.effects import CATALOGUE
from hexcal.sim import verdict_cases as vc


def _with_file(c, d, lead, tmp_path):
    """The diagnosis once the lead's written file is loaded from its path and added."""
    name = effect_name(lead)
    path = write_effect_file(lead, tmp_path / f"{name}.py", c.case)
    spec = importlib.util.spec_from_file_location(f"hexcal_effect_file_{name}", path)
    assert spec is not None and spec.loader is not None
    spec.loader.exec_module(importlib.util.module_from_spec(spec))
    try:
        return diagnose(
            c.meas, c.design, 42, add=[name], instruments=c.instruments, problem=d.problem
        )
    finally:
        CATALOGUE.pop(name, None)


@pytest.fixture(scope="module")
def dent():
    c = vc.foreign("stroke dent", 43)
    return c, diagnose(c.meas, c.design, 42, instruments=c.instruments)


def test_a_lead_that_predicts_readmitted_poses_worse_is_not_proposed(dent):
    _c, d = dent
    assert d.outliers, "the case needs poses set aside: the dent's deepest"
    assert d.exploration is not None
    rejected = [t for t in d.exploration.tested if any("it lets in" in n for n in t.notes)]
    assert rejected, "the stroke's spline, which readmits the dent's poses, was proposed"
    assert all(t.worse and not t.proposed for t in rejected)
    assert any("would be kept" in n for n in d.exploration.notes)


def test_the_proposed_leads_file_does_not_raise_the_heldout_error_on_the_same_poses(dent, tmp_path):
    c, d = dent
    lead = d.exploration.lead
    if lead is None:  # nothing proposed: never worse holds trivially, and is said
        assert d.exploration.notes
        return
    after = _with_file(c, d, lead, tmp_path)
    assert after.fit.cv_rms_mm < before_on_after_poses(d, after)
