"""Where a plan's question stands after the poses so far: the text UI's decide step records the
planned poses (:mod:`hexcal.diagnosis.plan`) one by one, diagnoses again after each, and asks
this module whether the question the diagnosis offered the plan for (an
:class:`~hexcal.diagnosis.plan_offer.Offer`) is decided.

It is decided as the diagnosis decides, at the verdict's own confidence
(:mod:`hexcal.diagnosis.verdict`, :mod:`hexcal.diagnosis.selection`): an effect is named on very
strong evidence (ΔBIC below −10), and two effects are told apart when their χ² differ by more
than the look-alike margin (Δχ² 10, a likelihood ratio of e⁵), Vuong's test of their poses puts
them 2 standard errors apart, and they do not both bring the residual to the floor.

- To separate A from B: the diagnosis names one of them, and not the other with it.
- To resolve E: E is no longer an effect the poses cannot tell from the geometry (its candidate
  is identifiable), whether it is then named or not.

The two hypotheses shown, with their χ² over the noise level: the pair; to resolve E, E against
the effect the diagnosis names (the geometry, :data:`~hexcal.diagnosis.plan.GEOMETRY`, when it
names none).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from hexcal.diagnosis.plan import GEOMETRY
from hexcal.diagnosis.plan_offer import Offer
from hexcal.estimate.effect_fit import fit_model
from hexcal.vocabulary import Outcome


@dataclass
class Standing:
    """The question after the poses so far: the two ``hypotheses``, their ``chi2`` (over the
    noise level, on the diagnosis' poses), whether it is ``decided``, the ``winner`` (the
    hypothesis named, or for a resolved effect not named, the geometry's side: None when
    undecided), and why, in ``words`` (:attr:`said`: with "decided" or "undecided" before)."""

    hypotheses: tuple[str, str]
    chi2: tuple[float, float]
    decided: bool
    winner: str | None
    words: str

    @property
    def said(self) -> str:
        return f"{'decided' if self.decided else 'undecided'}: {self.words}"

    @property
    def delta_chi2(self) -> float:
        """χ² of the second hypothesis less the first's (> 0: the first fits better)."""
        return self.chi2[1] - self.chi2[0]


def hypotheses(d: Any, offer: Offer) -> tuple[str, str]:
    """The two hypotheses whose χ² the decide step shows for ``offer`` at diagnosis ``d``."""
    if offer.kind == "separate":
        a, b = offer.hypotheses
        return a, b
    (e,) = offer.hypotheses
    named = str(d.verdict)
    rival = named if named != e and _is_effect(named) else GEOMETRY
    return e, rival


def standing(d: Any, offer: Offer, pair: tuple[str, str] | None = None) -> Standing:
    """Where ``offer``'s question stands at diagnosis ``d`` (of every pose so far); ``pair``:
    the hypotheses to show (None: :func:`hypotheses` of ``d`` — a decide step keeps those of
    the diagnosis that offered the plan, so that its rows compare the same two)."""
    pair = hypotheses(d, offer) if pair is None else pair
    chi2 = (_chi2(d, pair[0]), _chi2(d, pair[1]))
    named, alike = str(d.verdict), set(d.alike)
    if offer.kind == "separate":
        a, b = pair
        if named in pair:
            other = b if named == a else a
            if other not in alike:
                return Standing(pair, chi2, True, named, f"{named} — {other} no longer fits alike")
            why = f"{named} is named, {other} still fits alike"
        else:
            why = f"the diagnosis names {_said(named)}, neither of the two"
        return Standing(pair, chi2, False, None, why)
    (e,) = offer.hypotheses
    c = next((c for c in d.candidates if c.effect == e), None)
    if e in d.effects or named == e:
        more = f" ({', '.join(sorted(alike))} fit alike)" if alike else ""
        return Standing(pair, chi2, True, e, f"{e} is resolved and named{more}")
    if c is not None and c.identifiable:
        return Standing(
            pair,
            chi2,
            True,
            pair[1],
            f"{e} is resolved, and it is not what is missing ({_said(named)})",
        )
    reason = c.reason if c is not None and c.reason else f"{e} is not resolved yet"
    return Standing(pair, chi2, False, None, reason)


def _said(verdict: str) -> str:
    return f"verdict {verdict}" if not _is_effect(verdict) else verdict


def _is_effect(verdict: str) -> bool:
    """Whether a verdict names an effect (not an outcome: ``none``, ``unexplained``…)."""
    return verdict not in {o.value for o in Outcome}


def _chi2(d: Any, h: str) -> float:
    """χ² over the noise level of the diagnosis' model with hypothesis ``h`` (the model as it
    is for :data:`GEOMETRY` or an effect it holds), refitted where the diagnosis has not."""
    s2 = float(d.noise_level)
    if h == GEOMETRY or h in d.effects:
        return float(d.fit.chi2) / s2
    c = next((c for c in d.candidates if c.effect == h and c.refit is not None), None)
    if c is not None:
        return float(c.refit.chi2) / s2
    try:
        fit = fit_model(d.problem, (*d.effects, h), cross_validate=False, seed_fit=d.fit)
    except (ValueError, np.linalg.LinAlgError):
        return float("nan")  # a fit these poses cannot make: shown as such
    return float(fit.chi2) / s2
