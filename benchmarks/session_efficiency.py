"""Efficiency of `hexcal calibrate`'s whole-robot refinement on a whole session.

    python benchmarks/session_efficiency.py [--trials 300] [--seed 0] [--noise 0.1 0.01 0.1]
                                            [--poses 8 8 8 40]

One simulated session (Type I, II and III poses per leg, then free poses; the default is the
184-pose session `hexcal simulate` writes) is measured ``--trials`` times with fresh Gaussian
noise (position mm, orientation deg per axis, reading mm) and refined from the leg lengths
alone and with the clamps' constraints. Printed: for base points, platform points and offsets,
the Cramér–Rao bound of the full likelihood (RMS), each refinement's RMS error, efficiency =
bound / mean squared error, and bias (largest |mean error| of a coordinate over its σ).
"""

# ruff: noqa: E402  (the BLAS thread count is set before numpy is imported)
from __future__ import annotations

from hexcal.app.cli import single_thread_blas

single_thread_blas()  # as the CLI does

import argparse
import time

from hexcal.sim.robots import left_hand
from hexcal.sim.session_efficiency import efficiency_table, session_efficiency
from hexcal.sim.session_sim import SessionPlan
from hexcal.sim.simulate import NoiseModel


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--trials", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--noise", type=float, nargs=3, default=(0.1, 0.01, 0.1))
    ap.add_argument("--poses", type=int, nargs=4, default=(8, 8, 8, 40),
                    help="Type I, II, III poses per leg, then free poses")  # fmt: skip
    args = ap.parse_args()
    plan = SessionPlan(*args.poses)
    noise = NoiseModel(*args.noise)
    t0 = time.perf_counter()
    fig = session_efficiency(left_hand(), noise, args.trials, args.seed, plan)
    print(
        f"session of {6 * sum(args.poses[:3]) + args.poses[3]} poses, noise {args.noise[0]} mm / "
        f"{args.noise[1]}° / {args.noise[2]} mm (Gaussian), {args.trials} trials, seed {args.seed}"
    )
    print(efficiency_table(fig))
    print(f"{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
