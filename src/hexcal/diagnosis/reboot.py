"""A leg's encoder rebooted while recording: a zero step tested at that pose first.

The session marks the first pose recorded after a leg's encoder rebooted
(:mod:`hexcal.procedure.reboots`). An encoder that kept no preset reads off by a constant from
there on: a zero step of that leg at that pose, known in advance. So it is tested there alone
— one split, not the change-point search over every split of :mod:`hexcal.diagnosis.changepoint`
— by the same score: the step's column (the leg's whitened reading from that pose on), the
model's own parameters projected out through their normal equations, gives the χ² the step
removes over the session's noise level, and its size to first order. One test per reboot, at
:data:`REBOOT_ALPHA`: far more sensitive than the search, whose threshold pays for every split.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from hexcal.diagnosis.score import span_pinv
from hexcal.estimate.effect_fit import ModelFit, Problem
from hexcal.estimate.quantiles import chi2_isf

#: False-alarm probability of each reboot's test (one split, known in advance).
REBOOT_ALPHA = 1e-3


@dataclass(frozen=True)
class RebootStep:
    """The zero step tested at a reboot: leg (1-based), the first pose after the reboot,
    ``size_mm`` (how much longer the leg reads from there on, first order), the χ² it removes
    over the noise level and the threshold it had to exceed."""

    leg: int
    pose_id: int
    size_mm: float
    chi2: float
    threshold: float

    @property
    def off(self) -> bool:
        """The encoder came back off its zero."""
        return self.chi2 > self.threshold

    def text(self) -> str:
        head = f"leg {self.leg}'s encoder rebooted at pose {self.pose_id}"
        if self.off:
            how = "long" if self.size_mm > 0 else "short"
            return (
                f"{head} and came back {abs(self.size_mm):.1f} mm off: check its zero (re-home, "
                f"or restore its preset); it reads {how} from there on (a zero step at that pose "
                f"removes χ² {self.chi2:.0f}, threshold {self.threshold:.1f})"
            )
        return (
            f"{head} and came back at its zero (a step there: {1000 * self.size_mm:+.0f} µm, "
            f"χ² {self.chi2:.1f} under the threshold {self.threshold:.1f})"
        )

    def to_dict(self) -> dict:
        return {
            "leg": self.leg,
            "pose_id": self.pose_id,
            "size_mm": self.size_mm,
            "chi2": self.chi2,
            "threshold": self.threshold,
            "off": self.off,
            "text": self.text(),
        }


#: Refits of the size of a step found (see :func:`reboot_steps`).
SIZE_ROUNDS = 2


def reboot_steps(
    problem: Problem, fit: ModelFit, reboots: Sequence[tuple[int, int]], level: float = 1.0
) -> list[RebootStep]:
    """The zero step of each reboot ``(leg, first pose id after it)`` tested at ``fit`` of
    ``problem``'s poses (module docstring); the score is divided by the noise ``level`` (s²).
    A reboot whose pose was left out is tested at the next pose kept; one before the first
    pose or after the last is not tested. The size of a step found is first order at a fit
    that spread it over the geometry (millimetres of step pull the geometry by as much, 0.2 %
    off at 7 mm): it is refined by refitting the model with the step taken out of the
    readings, :data:`SIZE_ROUNDS` times, each adding the step the refit still sees."""
    out = _tested(problem, fit, reboots, level)
    for k, found in enumerate(out):
        if found.off:
            out[k] = replace(found, size_mm=_refined(problem, fit, found, level))
    return out


def _refined(problem: Problem, fit: ModelFit, found: RebootStep, level: float) -> float:
    """``found``'s size, refitted (see :func:`reboot_steps`)."""
    from hexcal.estimate.effect_fit import fit_model

    size = found.size_mm
    after = np.asarray(problem.meas.pose_id) >= found.pose_id
    for _ in range(SIZE_ROUNDS):
        readings = problem.meas.readings.copy()
        readings[after, found.leg - 1] -= size
        meas = replace(problem.meas, readings=readings)
        again = Problem.build(meas, problem.design, problem.sigmas)
        refit = fit_model(again, fit.effects, cross_validate=False)
        (left,) = _tested(again, refit, [(found.leg, found.pose_id)], level)
        size += left.size_mm
    return size


def _tested(
    problem: Problem, fit: ModelFit, reboots: Sequence[tuple[int, int]], level: float
) -> list[RebootStep]:
    """:func:`reboot_steps`' test, the sizes first order."""
    meas = problem.meas
    ids = np.asarray(meas.pose_id)
    jw, rw, w = fit.refinement.whitened()
    m = len(ids)
    inv = span_pinv(jw.T @ jw)
    coef_r = inv @ (jw.T @ rw)
    threshold = float(chi2_isf(REBOOT_ALPHA, 1))
    out = []
    for leg, pose_id in reboots:
        later = np.nonzero(ids >= pose_id)[0]
        if len(later) == 0 or later[0] == 0:
            continue
        i = int(later[0])
        s3 = np.zeros((m, 6))
        s3[i:] = w[i:, :, leg - 1]
        step = s3.reshape(-1)
        a = jw.T @ step
        norm2 = float(step @ step - a @ inv @ a)
        if norm2 <= 1e-8 * float(step @ step):
            continue  # the model's own columns hold this step (an offset alone): not testable
        dot = float(step @ rw - a @ coef_r)
        # The whitened residual is the prediction less the reading (changepoint's sign).
        out.append(RebootStep(leg, int(ids[i]), -dot / norm2, dot**2 / norm2 / level, threshold))
    return out
