"""The place in the procedure within its step (hexcal.effects.covariates ``step_time``): the
time since the pose's procedure step began, anew wherever the step changes in recording order,
carried through a subset of the poses; and, hidden as a settling anew in every step, the
explorer names it."""

from __future__ import annotations

import dataclasses

import numpy as np
from statcheck import floor_limit

from hexcal.app.workflow import Inputs, diagnose_chain
from hexcal.effects.covariates import covariate_values
from hexcal.effects.explored import ExploredEffect, line
from hexcal.estimate.effect_fit import Problem
from hexcal.sim import verdict_cases as vc


def _data(steps, t):
    """A session's first poses with the steps ``steps`` recorded at the times ``t``, s."""
    c = vc.foreign("settling per step", 0)
    sub = Problem.build(c.meas, c.design, None).data.subset(np.arange(len(t)))
    step = None if steps is None else np.array(steps, object)
    return dataclasses.replace(sub, t=np.asarray(t, float), step=step)


def test_step_time_restarts_where_the_step_changes():
    steps = ["a", "a", "a", "b", "b", "a", "free", "free"]
    t = [0.0, 5.0, 9.0, 20.0, 26.0, 40.0, 50.0, 61.0]
    got = covariate_values("step_time", _data(steps, t))
    # By hand: a step begins at rows 0, 3, 5 and 6 (a step revisited begins anew).
    np.testing.assert_array_equal(got[:, 0], [0.0, 5.0, 9.0, 0.0, 6.0, 0.0, 0.0, 11.0])
    assert np.all(got == got[:, :1])  # a quantity of the pose: the same for the six legs


def test_poses_from_no_procedure_are_one_step():
    d = _data(None, [3.0, 4.0, 8.0, 10.0])
    np.testing.assert_array_equal(covariate_values("step_time", d)[:, 0], [0.0, 1.0, 5.0, 7.0])


def test_a_subset_keeps_its_steps():
    d = _data(["a", "a", "b", "b"], [0.0, 2.0, 5.0, 9.0])
    sub = d.subset(np.array([1, 3]))
    assert list(sub.step) == ["a", "b"]
    # An effect along it evaluates on the subset's own steps (each row its step's start).
    eff = ExploredEffect("by_step_time_test", "step_time", line(np.zeros((2, 6)) + [[0.0], [1.0]]))
    assert np.all(np.isfinite(eff.basis(sub)))


def test_a_settling_in_every_step_is_named_by_the_time_since_the_step_began():
    c = vc.foreign("settling per step", 1)
    chain = diagnose_chain(Inputs(c.meas, c.design, c.instruments, "stated", c.case), 42, auto=True)
    last = chain[-1]
    lead = last.exploration.lead
    assert lead is not None and lead.covariate.name == "step_time", last.exploration.summary()
    assert lead.cv_rms_after_mm <= floor_limit(last, extra_params=lead.columns)
