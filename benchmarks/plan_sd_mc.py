"""The planner's predicted Δχ² spread, Monte-Carlo'd: for a look-alike session and its plan
(:mod:`benchmarks.plan_rates`), the planned poses recorded again and again with fresh noise,
the session's poses held as recorded; the realised Δχ² (the other hypothesis' χ² less the
true one's, both refitted on every pose) over the redraws against the plan's prediction.

    python benchmarks/plan_sd_mc.py [--pairs ...] [--sessions 2] [--draws 100]

With the session held, what is left to spread the Δχ² is the new poses' noise: its standard
deviation should be the plan's noise part (``Plan.noise_sd``); the plan's full sd adds the
spread of the session's own estimate, which only a new session redraws (the benchmark's z
over sessions, plan_rates.py, checks that part).
"""

# ruff: noqa: E402  (the BLAS thread count is set before numpy is imported)
from __future__ import annotations

from hexcal.app.cli import single_thread_blas

single_thread_blas()

import argparse
import json

import numpy as np
from plan_rates import _fits, ambiguous

from hexcal.diagnosis.plan import plan_poses
from hexcal.estimate.effect_fit import Problem
from hexcal.model.noise import NoiseSigmas
from hexcal.sim.plan_cases import PAIRS


def one(pair: str, seed: int, draws: int) -> dict:
    c, _, _ = ambiguous(pair, seed)
    if c is None:
        return {"pair": pair, "seed": seed, "ambiguous": False}
    problem = Problem.build(c.meas, c.design, NoiseSigmas.from_instruments(c.instruments))
    plan = plan_poses(problem, ("offset",), 20, separate=c.pair, rng=np.random.default_rng(seed))
    true = c.hidden
    other = next(h for h in c.pair if h != true)
    P, R, t = plan.meas.position, plan.meas.rotations.as_matrix(), plan.meas.t
    realised = []
    for k in range(draws):
        f = _fits(c.record(P, R, t, 10_000 + k, plan.meas.temperature), c)
        realised.append(f[other][1] - f[true][1])
    mean, sd = plan.expected[true]
    r = np.array(realised)
    return {
        "pair": pair,
        "seed": seed,
        "ambiguous": True,
        "hidden": true,
        "predicted_mean": mean,
        "predicted_sd": sd,
        "predicted_noise_sd": plan.noise_sd[true],
        "realised_mean": float(r.mean()),
        "realised_sd": float(r.std(ddof=1)),
        "draws": draws,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", nargs="+", default=list(PAIRS))
    ap.add_argument("--sessions", type=int, default=2)
    ap.add_argument("--draws", type=int, default=100)
    args = ap.parse_args()
    for pair in args.pairs:
        for seed in range(args.sessions):
            print(json.dumps(one(pair, seed, args.draws)), flush=True)


if __name__ == "__main__":
    main()
