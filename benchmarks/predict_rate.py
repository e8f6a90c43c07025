"""``hexcal predict``'s rate, readings → poses, in-process, against a plain batched Newton.

    python benchmarks/predict_rate.py [--rows 100000] [--runs 5]

The model is the left-hand robot's Model 42 and the same with a ``gain`` effect (what
``hexcal predict`` loads from calibrated.json); the readings are those of ``--rows`` random
poses (±20 mm, ±0.15 rad about home), solved from home as the guess by
:meth:`hexcal.estimate.predict.LegModel.poses`. The reference, taken in the same run, is the
plainest batched Newton on the same readings written here with numpy alone: the six leg
lengths' residual, its 6×6 Jacobian in (position, small rotation), ``np.linalg.solve`` over all
rows at once, a fixed 6 iterations — no effects, no checks, no convergence bookkeeping. Prints
poses per second (median of ``--runs``) and the ratio; both agree with the true poses to the
printed distance. Numbers, no pass or fail (docs/performance.md).
"""

# ruff: noqa: E402  (the BLAS thread count is set before numpy is imported)
from __future__ import annotations

from hexcal.app.cli import single_thread_blas

single_thread_blas()

import argparse
import statistics
import time

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.estimate.predict import LegModel
from hexcal.sim.robots import left_hand


def plain_newton(a, b, lengths, p0, r0, iterations: int = 6):
    """(N, 3) positions, (N, 3, 3) rotations whose legs have ``lengths`` (N, 6) mm: Newton
    from ``p0`` (3,), ``r0`` (3, 3) for every row at once."""
    n = len(lengths)
    p = np.repeat(p0[None], n, 0)
    r = np.repeat(r0[None], n, 0)
    for _ in range(iterations):
        rb = np.einsum("nij,kj->nki", r, b)  # (N, 6, 3)
        v = p[:, None, :] + rb - a[None]
        length = np.linalg.norm(v, axis=-1)
        u = v / length[..., None]
        jac = np.concatenate([u, np.cross(rb, u)], axis=-1)  # d|v| / (dp, dω)
        step = np.linalg.solve(jac, (lengths - length)[..., None])[..., 0]
        p = p + step[:, :3]
        r = Rotation.from_rotvec(step[:, 3:]).as_matrix() @ r
    return p, r


def rate(fn, rows: int, runs: int) -> float:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return rows / statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=100_000)
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    robot = left_hand()
    home = np.asarray(robot.home.position, float)
    P = home + rng.uniform(-20, 20, (args.rows, 3))
    R = Rotation.from_rotvec(rng.uniform(-0.15, 0.15, (args.rows, 3))).as_matrix()
    a, b = np.asarray(robot.a, float), np.asarray(robot.b, float)
    r0 = Rotation.from_quat(np.asarray(robot.home.quaternion), scalar_first=True).as_matrix()
    for effects, theta in (((), np.zeros(0)), (("gain",), rng.uniform(-1000, 1000, 6))):
        model = LegModel(robot, effects, theta)
        rho = model.readings(P, R)
        name = "Model 42" + "".join(f" + {e}" for e in effects)
        got = rate(lambda model=model, rho=rho: model.poses(rho), args.rows, args.runs)
        err = np.abs(model.poses(rho).position - P).max()
        print(f"{name:<18} LegModel.poses   {got / 1e3:8.1f} k poses/s  (max error {err:.1e} mm)")
        if not effects:
            lengths = np.linalg.norm(P[:, None] + np.einsum("nij,kj->nki", R, b) - a, axis=-1)
            ref = rate(
                lambda lengths=lengths: plain_newton(a, b, lengths, home, r0), args.rows, args.runs
            )
            perr = np.abs(plain_newton(a, b, lengths, home, r0)[0] - P).max()
            print(
                f"{'':<18} plain Newton     {ref / 1e3:8.1f} k poses/s  (max error {perr:.1e} mm)"
            )
            print(f"{'':<18} ratio            {got / ref:8.2f}")


if __name__ == "__main__":
    main()
