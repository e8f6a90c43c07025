"""Where a plan's question stands (:mod:`hexcal.diagnosis.decide`): decided as the diagnosis
decides — a pair when one is named and the other no longer fits alike, an effect to resolve
once the poses tell it from the geometry — with the two hypotheses' χ² over the noise level."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from hexcal.diagnosis.decide import hypotheses, standing
from hexcal.diagnosis.plan import GEOMETRY
from hexcal.diagnosis.plan_offer import Offer


def _d(verdict, alike=(), chi2=None, effects=("offset",), fit=200.0, s2=1.0, **cand):
    """A diagnosis as far as the decide step reads it: ``chi2`` the refits' χ², ``cand`` an
    identifiable flag (and reason) per candidate."""
    chi2 = chi2 or {}
    names = set(chi2) | set(cand)
    candidates = [
        SimpleNamespace(
            effect=e,
            refit=SimpleNamespace(chi2=chi2[e]) if e in chi2 else None,
            identifiable=cand.get(e, (True, ""))[0],
            reason=cand.get(e, (True, ""))[1],
        )
        for e in sorted(names)
    ]
    return SimpleNamespace(
        verdict=verdict,
        alike=list(alike),
        candidates=candidates,
        effects=effects,
        fit=SimpleNamespace(chi2=fit),
        noise_level=s2,
    )


PAIR = Offer("separate", ("gain", "compliance"), 8)
RESOLVE = Offer("resolve", ("thermal",), 3)


def test_a_pair_is_decided_when_one_is_named_and_the_other_no_longer_fits_alike():
    chi2 = {"gain": 100.0, "compliance": 130.0}
    alike = standing(_d("gain", ["compliance"], chi2), PAIR)
    assert not alike.decided and alike.winner is None
    assert alike.said == "undecided: gain is named, compliance still fits alike"
    apart = standing(_d("compliance", [], chi2), PAIR)
    assert apart.decided and apart.winner == "compliance"
    assert apart.said == "decided: compliance — gain no longer fits alike"
    assert apart.chi2 == (100.0, 130.0) and apart.delta_chi2 == pytest.approx(30.0)
    other = standing(_d("backlash", [], chi2), PAIR)
    assert not other.decided and "names backlash, neither of the two" in other.words


def test_an_effect_to_resolve_is_decided_once_the_poses_tell_it_from_the_geometry():
    why = "thermal.alpha cannot be told apart from offset3 with these poses"
    stuck = _d("drift", ["frame_step"], {"drift": 150.0, "thermal": 160.0}, thermal=(False, why))
    assert hypotheses(stuck, RESOLVE) == ("thermal", "drift")
    st = standing(stuck, RESOLVE)
    assert (st.decided, st.words, st.chi2) == (False, why, (160.0, 150.0))
    named = standing(_d("thermal", ["drift"], {"thermal": 120.0, "drift": 140.0}), RESOLVE)
    assert named.decided and named.winner == "thermal"
    assert named.words == "thermal is resolved and named (drift fit alike)"
    # Resolved and not named: the geometry's side wins; its χ² the model's own, over s².
    absent = standing(_d("none", chi2={"thermal": 390.0}, fit=400.0, s2=2.0), RESOLVE)
    assert absent.hypotheses == ("thermal", GEOMETRY) and absent.winner == GEOMETRY
    assert absent.decided and absent.chi2 == (195.0, 200.0)
    assert absent.words == "thermal is resolved, and it is not what is missing (verdict none)"
    # The pair shown can be held to the first diagnosis' while the verdict moves on.
    held = standing(_d("frame_step", chi2={"thermal": 1.0, "drift": 2.0}), RESOLVE, stuck_pair())
    assert held.hypotheses == ("thermal", "drift")


def stuck_pair() -> tuple[str, str]:
    return ("thermal", "drift")
