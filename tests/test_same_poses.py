"""A diagnosis chain's steps compared on one set of poses (hexcal.diagnosis.same_poses).

A dent on one leg (``stroke dent``, seed 11): Model 42 sets 9 of the dent's poses aside; the
explorer's spline along the stroke, added by ``--auto --explore``, readmits all of them. The
second step's held-out RMS is then over 184 poses, the first's over 175: the chain must give
the first step's model on the second step's poses, the figure the fall is to be read against.
"""

from __future__ import annotations

import json
import math

import numpy as np

from hexcal.app.workflow import Inputs, diagnose_chain
from hexcal.diagnosis.same_poses import before_on_after_poses, same_poses
from hexcal.effects import CATALOGUE
from hexcal.estimate.effect_fit import fit_model
from hexcal.sim import verdict_cases as vc


def test_a_step_that_keeps_other_poses_is_compared_on_its_own(tmp_path):
    c = vc.foreign("stroke dent", 11)
    before = set(CATALOGUE)
    try:
        chain = diagnose_chain(
            Inputs(c.meas, c.design, c.instruments, "stated", c.case),
            42,
            auto=True,
            explore_dir=tmp_path,
        )
        assert len(chain) >= 2
        first, second = chain[0], chain[1]
        assert not same_poses(first, second), "the case needs the file to readmit poses"
        assert len(second.problem.meas) > len(first.problem.meas)
        # the figure is the first step's model refitted on the second step's poses, computed
        # here apart from the chain
        ref = fit_model(second.problem, first.fit.effects).cv_rms_mm
        assert math.isclose(second.cv_rms_before_mm, ref, rel_tol=1e-9)
        assert math.isclose(before_on_after_poses(first, second), ref, rel_tol=1e-9)
        # the added spline predicts those poses better, though its RMS over them is higher
        # than the first step's over fewer
        assert second.fit.cv_rms_mm < ref
        note = next(n for n in second.notes if "set aside at the step before" in n)
        assert f"{1000 * ref:.2f} µm" in note
        row = json.loads(json.dumps(second.to_dict()))
        assert np.isclose(row["cv_rms_before_same_poses_mm"], ref)
        assert first.to_dict()["cv_rms_before_same_poses_mm"] is None
    finally:
        for name in set(CATALOGUE) - before:
            CATALOGUE.pop(name, None)
