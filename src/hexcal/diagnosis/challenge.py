"""A catalogue verdict challenged by the explorer: a named effect and a shape outside the
catalogue compared as look-alikes, on the poses neither was fitted to.

Why: the catalogue is judged first, and an effect that brings the residual to the floor is
named. Yet an effect outside the catalogue can share most of its signature on the poses
recorded: two legs reading a third leg's stroke (cross-talk) look like a gain error on
those two legs, since on a hexapod one leg's stroke follows the others'; the catalogue's
``gain`` closed that excess in 7 of 50 sessions and the cross-talk was never named. The
in-sample χ² of two such fits differs by little, and by a margin that each fit's parameter
count decides. Their held-out predictions differ by what their physics differs by.

So where the catalogue names an effect over a significant excess, and it brings the residual
to the floor alone (where it needs others, several effects hide, and a lead would take up some
of each: gain, thermal expansion and backlash at once met a force × stroke × last move that
beat backlash alone), the explorer is run on
the model without it (:func:`~hexcal.diagnosis.explorer.explore`: its leads are refitted for
real) and its headline lead is compared with the named effect's refit, pose by pose on
held-out poses (:func:`~hexcal.diagnosis.selection.heldout_gain`):

- the lead fits differently (not the catalogue effect written again:
  :func:`~hexcal.diagnosis.selection.fit_apart`) and
  predicts better by more than :data:`CHALLENGE_Z` standard errors: the verdict is
  ``unexplained`` with that lead (the catalogue effect said to fit less well);
- neither predicts better beyond it, and their fits differ (not one model written twice, as
  a straight line in each leg's stroke is ``gain``): both are named, with the motions that
  would separate them;
- the catalogue effect predicts better: it stands, and nothing is said.
"""

from __future__ import annotations

from dataclasses import dataclass

from hexcal.diagnosis.explorer import Exploration, explore
from hexcal.diagnosis.leads import Lead
from hexcal.diagnosis.scoring import Candidate, pose_whiteners
from hexcal.diagnosis.selection import HELDOUT_Z, fit_apart, heldout_gain
from hexcal.effects import get_effect
from hexcal.estimate.effect_fit import ModelFit, Problem

#: The paired held-out test's z beyond which one of the two predicts better (the threshold
#: the verdict's own held-out test uses).
CHALLENGE_Z = HELDOUT_Z


@dataclass
class Challenge:
    """The explorer's answer to a catalogue verdict."""

    exploration: Exploration
    lead: Lead
    z: float  #: the lead's held-out gain over the named effect's, in standard errors
    distinct: bool  #: the two fits differ beyond what one model refitted would (fit_apart)
    named: str  #: the catalogue effect challenged

    @property
    def overturns(self) -> bool:
        return self.distinct and self.z > CHALLENGE_Z

    @property
    def alike(self) -> bool:
        return self.distinct and abs(self.z) <= CHALLENGE_Z

    def note(self) -> str:
        """What the diagnosis says of the comparison (empty where the named effect stands
        alone)."""
        eff, lead = get_effect(self.named), self.lead
        said = (
            f"{lead.covariate.label} ({lead.covariate.name}; "
            f"{lead.shape.describe(lead.covariate.unit)} on {lead.where()})"
        )
        if self.overturns:
            return (
                f"{self.named} brings the residual near the floor too, but a shape outside the "
                f"catalogue predicts the held-out poses better, by {self.z:.1f} standard errors "
                f"pose by pose: {said}, held-out RMS {1000 * lead.cv_rms_after_mm:.2f} µm. "
                f"{self.named} is a look-alike here, not the answer"
            )
        if self.alike:
            return (
                f"{self.named} or {said}: these poses cannot tell them apart (held-out RMS "
                f"{1000 * lead.cv_rms_after_mm:.2f} µm with the lead; the paired held-out "
                f"test {self.z:+.1f} σ). {self.named} is taken first as the catalogue's; record "
                f"{eff.separating_motion}; and poses spreading the {lead.covariate.label} over its "
                "range, to separate them"
            )
        return ""


def challenge(
    problem: Problem, fit: ModelFit, named: Candidate, s2: float, level: float
) -> Challenge | None:
    """The explorer's best lead on ``fit`` (the model without ``named``) against ``named``'s
    refit (see the module docstring); None where the explorer proposes nothing."""
    if named.refit is None or not named.closes or named.with_effect:
        return None  # several effects hide: the lead would take up some of each, not one
    ex = explore(problem, fit, s2, level)
    lead = ex.lead
    if lead is None or lead.refit is None:
        return None
    chol = pose_whiteners(problem, fit)
    _, z = heldout_gain(named.refit, lead.refit, chol, s2)
    return Challenge(ex, lead, z, fit_apart(named.refit, lead.refit, chol, s2), named.effect)
