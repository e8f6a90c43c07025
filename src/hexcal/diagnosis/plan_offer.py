"""The plans a diagnosis offers (:func:`offers`): where two candidates are look-alikes, or an
effect cannot be told from the geometry, how many planned poses (:mod:`hexcal.diagnosis.plan`)
would decide, and after what wait — said in the text, ``--json``, the report and the text UI,
with the ``hexcal plan`` command that makes them (:meth:`Offer.args`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hexcal.diagnosis import selection
from hexcal.diagnosis.plan import (
    When,
    _candidates,
    _Criterion,
    _schedule,
    _setting,
    _times,
    _with_edges,
)
from hexcal.effects import get_effect
from hexcal.estimate.effect_fit import ModelFit, Problem

#: Planned poses beyond which a plan is not offered (the issue's "a dozen or two").
MAX_OFFER = 20
#: Candidate poses an offer picks from (fewer than a plan's: the diagnosis waits for it).
OFFER_CANDIDATES = 800
#: Planned poses offered to confirm what the recorded poses should already decide.
CONFIRM_POSES = 4
#: Unresolved candidates offered a plan, the best-scoring first.
MAX_RESOLVE_OFFERS = 2


@dataclass
class Offer:
    """A plan the diagnosis offers: how many planned poses would decide (None: more than
    :data:`MAX_OFFER`)."""

    kind: str  #: "separate" or "resolve"
    hypotheses: tuple[str, ...]
    poses: int | None
    #: s to wait after the session's last pose before the first planned one (a drift's pair:
    #: time separates it; :func:`waits_to_try`)
    wait_s: float = 0.0

    @property
    def n_planned(self) -> int:
        """How many poses to plan for it: its count, a few to confirm (0), at most
        :data:`MAX_OFFER` (None)."""
        return self.poses or (CONFIRM_POSES if self.poses == 0 else MAX_OFFER)

    def args(self) -> list[str]:
        """``hexcal plan``'s own arguments for it (after the session's)."""
        flag = "--separate" if self.kind == "separate" else "--resolve"
        wait = ["--wait", f"{self.wait_s:.0f}"] if self.wait_s > 0 else []
        return [flag, *self.hypotheses, "--poses", str(self.n_planned), *wait, "--out", "plan.csv"]

    def text(self) -> str:
        what = (
            f"tell {' from '.join(self.hypotheses)} apart"
            if self.kind == "separate"
            else f"resolve {self.hypotheses[0]}"
        )
        if self.poses is None:
            return f"more than {MAX_OFFER} planned poses would be needed to {what}"
        if self.poses == 0:
            return (
                f"the poses recorded should already {what} by their expected separation, though "
                "their χ² spread wider than the noise: a few planned poses confirm it"
            )
        after = f", recorded after a wait of {_minutes(self.wait_s)}" if self.wait_s > 0 else ""
        return f"{self.poses} planned poses{after} would {what}"

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "hypotheses": list(self.hypotheses),
            "poses": self.poses,
            "wait_s": self.wait_s,
        }


def _minutes(s: float) -> str:
    return f"{s / 60:.0f} min" if s >= 90 else f"{s:.0f} s"


def poses_to_decide(
    problem: Problem,
    effects: tuple[str, ...],
    separate: tuple[str, str] | None = None,
    resolve: str | None = None,
    rng: np.random.Generator | None = None,
    n_candidates: int = OFFER_CANDIDATES,
) -> tuple[int | None, float]:
    """(the fewest planned poses, at most :data:`MAX_OFFER` — None beyond — after which the
    question is decided; the wait before them, s, as :func:`plan_poses` chooses it): two
    hypotheses' expected separation, less two of its standard deviations, beyond the
    look-alike margin and what the parameter counts cost in ΔBIC
    (:func:`~hexcal.diagnosis.selection.separates`); an effect's every parameter resolved as
    the score test asks (:func:`~hexcal.diagnosis.scoring.needed_resolution`)."""
    from hexcal.diagnosis.scoring import needed_resolution

    rng = np.random.default_rng(0) if rng is None else rng
    hyps = tuple(separate) if separate is not None else (str(resolve),)
    setting = _setting(problem, effects, hyps)
    pool = _candidates(problem, setting.robot, n_candidates, rng)
    crit = _Criterion(setting, resolve is not None)
    n_max = min(MAX_OFFER, len(pool[0]))
    pool = _with_edges(problem, setting.robot, pool, rng)
    crit, wait, chosen = _schedule(crit, pool, n_max, When())
    t = _times(problem, setting.dt, n_max, wait)
    P, R = pool[0][chosen], pool[1][chosen]
    if resolve is None:
        return crit.decided_after(P, R, t), wait
    need = needed_resolution(get_effect(hyps[0]).params(problem.design))
    for n in range(0, n_max + 1):
        rows = crit._rows_at(P[:n], R[:n], t[:n])
        info = selection.schur_block(crit._gram(rows[0]), len(need))
        cov = np.linalg.pinv(info)
        if np.all(np.sqrt(np.clip(np.diag(cov), 0, None)) < need):
            return n, wait
    return None, wait


def offers(
    problem: Problem,
    fit: ModelFit,
    verdict: str,
    alike: list[str],
    candidates,
) -> list[Offer]:
    """The plans a diagnosis offers at ``fit``: to tell the verdict from each look-alike, and
    to resolve the candidates the poses cannot tell from the geometry whose columns together
    would remove more than the look-alike margin (their score counting every column, the
    unresolved ones too: worth deciding), the best first."""
    from hexcal.diagnosis.score import score_columns

    effects = fit.effects
    # Effects located by a search (a zero step's, a tracker move's time) have no basis to plan
    # with beyond the session's end: their pairs are not planned.
    named = (verdict, *alike) if alike else ()  # look-alikes come with an effect named
    searched = {e for e in named if getattr(get_effect(e), "searched_params", 0)}
    asked: list[tuple[str, tuple[str, ...]]] = [
        ("separate", (verdict, e)) for e in alike if not searched & {verdict, e}
    ]
    whole = {
        c.effect: score_columns(problem, fit, c.effect).score(
            np.ones(len(get_effect(c.effect).params(problem.design)), bool)
        )
        for c in candidates
        if c.available and not c.identifiable
    }
    stuck = [
        e for e, s in sorted(whole.items(), key=lambda kv: -kv[1]) if s >= selection.ALIKE_DCHI2
    ]
    asked += [("resolve", (e,)) for e in stuck]
    out = []
    for kind, hyps in asked[: len(asked) - len(stuck) + MAX_RESOLVE_OFFERS]:
        pair = (hyps[0], hyps[1]) if kind == "separate" else None
        what = None if pair else hyps[0]
        try:
            out.append(Offer(kind, hyps, *poses_to_decide(problem, effects, pair, what)))
        except (ValueError, np.linalg.LinAlgError):  # a fit these data cannot make: no offer
            continue
    return out
