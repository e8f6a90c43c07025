"""Experiments that decide: `hexcal plan` over simulated look-alike sessions.

    python benchmarks/plan_rates.py [--sessions 50] [--poses 20] [--jobs 2] [--pairs ...]
                                    [--lab-holds] [--out FILE.json] | --markdown FILE.json

For each pair of :mod:`hexcal.sim.plan_cases` (gain vs compliance on the motion base, thermal
vs drift, ujoint vs the geometry), sessions whose poses leave the pair ambiguous, one of the two
hidden. The planner picks at most ``--poses`` poses to separate them (:func:`hexcal.diagnosis.
plan.plan_poses`): the fewest of them after which it expects the question decided (``Plan.
decide``, what the diagnosis offers), else all; the same robot records them (the simulator with
the truth) at the plan's times and temperatures (its schedule: a wait, a temperature held), and,
as the control, as many random reachable poses from the same set recorded as the session goes
on, and again on the plan's schedule (what the schedule alone does). ``--lab-holds``: the
simulated lab can hold any temperature the session saw (the plan may choose one). After each,
both hypotheses are refitted on all the poses:

- named right: the true hypothesis' ΔBIC against the model is very strong
  (:data:`~hexcal.diagnosis.selection.BIC_STRONG`), it is the lower of the two, and the two are
  not look-alikes by the verdict's rule (the other fits worse by χ² 10 and by Vuong's z ≥ 2,
  whether or not both bring the residual to the floor); for the nested pair (the geometry
  alone against ujoint), ujoint's ΔBIC is very strong. The sessions are drawn until their own poses leave the pair undecided that way
  (:func:`ambiguous`);
- the predicted separation against the realised: z = (Δχ² realised − mean) / sd, the mean
  and sd the plan's for the true hypothesis — the predictive distribution of the Δχ² given
  the session's residuals (:func:`hexcal.diagnosis.selection.predicted_delta_chi2`: the new
  poses' residuals as the true hypothesis fitted to the session predicts them, with their
  noise and that fit's spread). If sd is right, |z| ≤ 1 in 68 % of sessions and |z| ≤ 2 in
  95 %.
"""

# ruff: noqa: E402  (the BLAS thread count is set before numpy is imported)
from __future__ import annotations

from hexcal.app.cli import single_thread_blas

single_thread_blas()

import argparse
import json
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from hexcal.diagnosis.plan import GEOMETRY, When, plan_poses
from hexcal.diagnosis.plan_pool import _candidates
from hexcal.diagnosis.scoring import pose_whiteners
from hexcal.diagnosis.selection import BIC_STRONG, bic_delta, indistinct, vuong_z
from hexcal.estimate.effect_fit import Problem, fit_model
from hexcal.model.noise import NoiseSigmas
from hexcal.sim.plan_cases import PAIRS, SIZES, case


def _fits(meas, c) -> dict:
    """Each hypothesis' (ΔBIC against the model, χ², parameter count), and ``"vuong"``:
    Vuong's z of the two (non-nested pairs)."""
    problem = Problem.build(meas, c.design, NoiseSigmas.from_instruments(c.instruments))
    base = fit_model(problem, ("offset",), cross_validate=False)
    out: dict = {GEOMETRY: (0.0, base.chi2, base.n_params), "dof": base.dof}
    made = {}
    for h in c.pair:
        if h == GEOMETRY:
            continue
        made[h] = fit_model(problem, ("offset", h), cross_validate=False, seed_fit=base)
        out[h] = (bic_delta(problem, base, made[h]), made[h].chi2, made[h].n_params)
    if len(made) == 2:
        (na, a), (nb, b) = made.items()
        z = vuong_z(a, b, pose_whiteners(problem, base))
        out["vuong"] = {(na, nb): z, (nb, na): -z}
    return out


def _alike(fits, best: str, other: str) -> bool:
    """The verdict's look-alike rule (:func:`hexcal.diagnosis.selection.indistinct`): ``other``
    does not fit worse than ``best`` by both χ² (ALIKE_DCHI2) and the poses' χ² beyond their
    noise (Vuong)."""
    return indistinct(fits[other][1] - fits[best][1], fits["vuong"][(other, best)])


def _right(fits, c) -> bool:
    """The true hypothesis named, alone: very strong evidence, the lower ΔBIC, and not alike."""
    true = c.hidden
    other = next(h for h in c.pair if h != true)
    if other == GEOMETRY:
        return bool(fits[true][0] < BIC_STRONG)
    dbic = fits[true][0]
    return bool(dbic < BIC_STRONG and dbic < fits[other][0] and not _alike(fits, true, other))


#: Tries per session at finding an ambiguous one (the effect's size drawn anew each time).
TRIES = 40


def ambiguous(pair: str, seed: int):
    """(case, fits on its poses, tries): the first session, the hidden effect's size drawn
    log-uniform over the pair's range (:data:`~hexcal.sim.plan_cases.SIZES`) × the case's,
    whose poses leave the pair undecided — both
    hypotheses with very strong evidence and alike by the verdict's rule (the diagnosis names
    them together), or, against the geometry, the hidden effect not named."""
    rng = np.random.default_rng([seed, 2])
    lo, hi = np.log(SIZES[pair])
    for k in range(TRIES):
        c = case(pair, seed + 1000 * k, float(np.exp(rng.uniform(lo, hi))))
        fits = _fits(c.meas, c)
        a, b = c.pair
        if a == GEOMETRY:
            undecided = not _right(fits, c)
        else:
            both = fits[a][0] < BIC_STRONG and fits[b][0] < BIC_STRONG
            best, other = (a, b) if fits[a][0] <= fits[b][0] else (b, a)
            undecided = both and _alike(fits, best, other)
        if undecided:
            return c, fits, k + 1
    return None, None, TRIES


def _lab(meas) -> tuple[float, float] | None:
    """The temperatures the simulated lab can hold: the session's own range."""
    temp = meas.temperature
    return None if temp is None else (float(np.min(temp)), float(np.max(temp)))


def _held(plan) -> float | None:
    temp = plan.meas.temperature
    return None if temp is None else float(temp[0])


def _rng(seed: int) -> np.random.Generator:
    return np.random.default_rng(seed)


def run_session(args: tuple[str, int, int, bool]) -> dict:
    pair, seed, n, lab_holds = args
    c, before, tries = ambiguous(pair, seed)
    if c is None:
        return {"pair": pair, "seed": seed, "ambiguous": False, "tries": tries}
    problem = Problem.build(c.meas, c.design, NoiseSigmas.from_instruments(c.instruments))
    when = When(temperatures=_lab(c.meas) if lab_holds else None)
    t0 = time.perf_counter()
    plan = plan_poses(problem, ("offset",), n, separate=c.pair, rng=_rng(seed), when=when)
    seconds = time.perf_counter() - t0
    if plan.decide is not None and 0 < plan.decide < n:  # the fewest that decide, as offered
        n = plan.decide
        # the same schedule (wait, temperature), fewer poses
        when = When(plan.wait, temperature=_held(plan))
        plan = plan_poses(problem, ("offset",), n, separate=c.pair, rng=_rng(seed), when=when)
    P, R, t = plan.meas.position, plan.meas.rotations.as_matrix(), plan.meas.t
    temp = plan.meas.temperature
    planned = _fits(c.record(P, R, t, seed, temp), c)
    rng = np.random.default_rng([seed, 1])
    Pr, Rr = _candidates(problem, c.simulator.robot, 4 * n, rng)
    # The control: as many random reachable poses recorded as the session goes on (no wait);
    # and the same poses after the plan's wait, at its temperature (what the timing alone does).
    t_now = np.round(t - plan.wait, 3)
    random = _fits(c.record(Pr[:n], Rr[:n], t_now, seed), c)
    waited = _fits(c.record(Pr[:n], Rr[:n], t, seed, temp), c) if plan.wait > 0 else random
    true = c.hidden
    other = next(h for h in c.pair if h != true)
    mean, sd = plan.expected.get(true, (float("nan"), float("nan")))
    realised = planned[other][1] - planned[true][1]
    return {
        "pair": pair,
        "seed": seed,
        "ambiguous": True,
        "tries": tries,
        "hidden": true,
        "poses": n,
        "right_before": _right(before, c),
        "right_planned": _right(planned, c),
        "right_random": _right(random, c),
        "right_random_waited": _right(waited, c),
        "wait_s": plan.wait,
        "predicted": mean,
        "predicted_sd": sd,
        "predicted_noise_sd": plan.noise_sd.get(true, float("nan")),
        "realised": realised,
        "z": (realised - mean) / sd if sd > 0 else float("nan"),
        "separation_before": plan.before,
        "separation_planned": plan.planned,
        "separation_random": plan.random,
        "random_to_match": plan.match,
        "plan_s": seconds,
    }


def summary(rows: list[dict]) -> dict:
    out = {}
    for pair in dict.fromkeys(r["pair"] for r in rows):
        every = [r for r in rows if r["pair"] == pair]
        rs = [r for r in every if r["ambiguous"]]
        if not rs:
            out[pair] = {"sessions": 0, "not_ambiguous_in_tries": len(every)}
            continue
        z = np.array([r["z"] for r in rs if np.isfinite(r["z"])])
        out[pair] = {
            "sessions": len(rs),
            "no_ambiguous_session_found": len(every) - len(rs),
            "right_before": float(np.mean([r["right_before"] for r in rs])),
            "right_planned": float(np.mean([r["right_planned"] for r in rs])),
            "right_random": float(np.mean([r["right_random"] for r in rs])),
            "right_random_waited": float(np.mean([r["right_random_waited"] for r in rs])),
            "median_wait_s": float(np.median([r["wait_s"] for r in rs])),
            "within_1sd": float(np.mean(np.abs(z) <= 1)) if len(z) else None,
            "within_2sd": float(np.mean(np.abs(z) <= 2)) if len(z) else None,
            "median_z": float(np.median(z)) if len(z) else None,
            "median_plan_s": float(np.median([r["plan_s"] for r in rs])),
            "median_poses": float(np.median([r["poses"] for r in rs])),
            "median_random_to_match": float(
                np.median([r["random_to_match"] or np.inf for r in rs])
            ),
        }
    return out


#: The pairs' rows in docs/diagnosis.md: (label, pair).
LABELS = {
    "ujoint vs geometry": "ujoint vs geometry (Left Hand)",
    "thermal vs drift": "thermal vs drift (Left Hand, 5 K rise)",
    "gain vs compliance": "gain vs compliance (motion base, gain hidden)",
}


def markdown(summary: dict, total: int) -> str:
    """docs/diagnosis.md's table of a run of ``total`` sessions per pair (``python
    plan_rates.py --markdown FILE.json`` prints it again from a run's --out)."""

    def pct(x: float, n: int) -> str:
        return f"{100 * x:.0f} %" if n >= 20 else f"{round(x * n)} of {n}"

    rows = [
        "| pair | ambiguous sessions | planned poses (median) | wait (median) | right after the "
        "planned | after as many random | random on the plan's schedule | \\|z\\| ≤ 1 | "
        "\\|z\\| ≤ 2 | random poses to match (median) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for pair, label in LABELS.items():
        s = summary.get(pair)
        if not s or not s.get("sessions"):
            continue
        n = s["sessions"]
        rows.append(
            f"| {label} | {n} of {total} | {s['median_poses']:.0f} | "
            f"{s['median_wait_s'] / 60:.0f} min | {pct(s['right_planned'], n)} "
            f"| {pct(s['right_random'], n)} | {pct(s['right_random_waited'], n)} | "
            f"{pct(s['within_1sd'], n)} | "
            f"{pct(s['within_2sd'], n)} | {s['median_random_to_match']:.0f} |"
        )
    return "\n".join(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=50)
    ap.add_argument("--poses", type=int, default=20)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--pairs", nargs="+", default=list(PAIRS))
    ap.add_argument("--out", help="write every session's row and the summary here (JSON)")
    ap.add_argument(
        "--lab-holds",
        action="store_true",
        help="the simulated lab can hold the rig at any temperature the session saw (changing "
        "it no faster than the session did): the plan chooses the temperature too",
    )
    ap.add_argument("--markdown", metavar="JSON", help="print the table of a run's --out, and stop")
    args = ap.parse_args()
    if args.markdown:
        with open(args.markdown) as f:
            done = json.load(f)
        total = max(Counter(r["pair"] for r in done["sessions"]).values())
        print(markdown(done["summary"], total))
        return
    work = [(p, s, args.poses, args.lab_holds) for p in args.pairs for s in range(args.sessions)]
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(run_session, work))
    result = {"poses": args.poses, "summary": summary(rows), "sessions": rows}
    print(json.dumps(result["summary"], indent=2))
    print(markdown(result["summary"], args.sessions))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=1)


if __name__ == "__main__":
    main()
