"""Live ranking while recording: the time per pose of :class:`hexcal.diagnosis.live_rank.
LiveRanking` (add the pose, rank the candidates, name the leader and its margin).

    python benchmarks/live_rank.py [--poses 1000] [--effect gain]

A Left Hand session of ``--poses`` poses (the clamped sets, then free poses) with ``--effect``
hidden at its realistic size, fed pose by pose; printed: the median, 95th percentile and
largest time per pose over the last hundred poses and over all (the largest is a pose where the
linearisation moves and the normal equations are rebuilt from every pose), and the leader at
the end.
"""

# ruff: noqa: E402  (the BLAS thread count is set before numpy is imported)
from __future__ import annotations

from hexcal.app.cli import single_thread_blas

single_thread_blas()

import argparse
import time

import numpy as np

from hexcal.diagnosis.live_rank import LiveRanking
from hexcal.model.noise import NoiseSigmas
from hexcal.sim import verdict_cases as vc
from hexcal.sim.inject import effect_hook, realistic_values
from hexcal.sim.robots import left_hand
from hexcal.sim.session_sim import SessionPlan, perturbed_truth, simulate_session


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=1000)
    ap.add_argument("--effect", default="gain")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    design = left_hand().model_copy(update={"platform_mass_kg": 20.0})
    rng = np.random.default_rng(args.seed)
    plan = SessionPlan(temperature_rise_k=5.0, n_free=max(args.poses - 144, 0))
    truth = perturbed_truth(design, rng, plan)
    hook = effect_hook(args.effect, realistic_values(args.effect, rng, truth), truth)
    meas, _ = simulate_session(design, args.seed, plan, effects=[hook], truth=truth)
    live = LiveRanking(design, NoiseSigmas.from_instruments(vc.INSTRUMENTS))
    R = meas.rotations.as_matrix()
    ms = []
    for i in range(len(meas)):
        t0 = time.perf_counter()
        live.add(meas.position[i], R[i], meas.readings[i], meas.t[i], meas.temperature[i])
        leader, margin = live.leader()
        ms.append(1000 * (time.perf_counter() - t0))
    ms_arr = np.array(ms)
    for label, part in (("last 100 poses", ms_arr[-100:]), ("all poses", ms_arr)):
        print(
            f"{label}: median {np.median(part):.1f} ms, 95th percentile "
            f"{np.percentile(part, 95):.1f} ms, largest {part.max():.1f} ms per pose"
        )
    name = leader.effect if leader else "none"
    print(f"{len(meas)} poses, {args.effect} hidden: the leader {name}, margin ΔBIC {margin:.0f}")


if __name__ == "__main__":
    main()
