"""Time alignment between the tracker's poses and the leg readings, through the real drivers.

    python benchmarks/alignment.py --seconds 20 [--jitter-ms 3] [--delay-ms 5] [--can-jitter-ms 2]

Runs the simulated rig as ``hexcal devices check --mock`` does (one MockRobot behind an
``ndimock://`` tracker and six mock CANopen encoders on python-can's virtual bus), built here so
that the tracker's replies can be delayed (``--delay-ms`` + U(0, ``--jitter-ms``)) and the
encoders' TPDOs jittered (``--can-jitter-ms``). The robot moves every ``--move-ms`` (so every
sample's true instant matters) while two threads read both streams as acquisition does:
``NDITracker.sample(binary=True)`` and ``LegEncoders.read_set()``.

Ground truth comes from the mocks: the instant the mock tracker measured each frame number
(``MockNDITracker.frame_times``) and the instant each encoder reading set was latched
(``MockRobot.encoder_latches``, matched to the mock nodes' ``history`` entry of each SYNC
counter by identity of the readings array). Printed as JSON, in ms, each as mean / p1 / p50 /
p99 / max (signed), p99_abs and max_abs, after ``--warmup`` s:

- ``tracker.stamp_error_ms``: ``TrackerSample.t`` - the frame's true instant;
- ``tracker.receive_error_ms``: the reply's arrival - the true instant (the old stamp);
- ``legs.stamp_error_ms``: the set's ``t_sync`` (``LegSample.t``) - the true latch instant;
- ``alignment_error_ms``: for each tracker sample paired with the leg set stamped nearest to
  it (as acquisition pairs them), tracker stamp error - leg stamp error: how wrong the time
  between the pose and the readings paired with it is (and the same had the tracker been
  stamped on receipt, as before the frame clock).

Two cores suffice: five light threads (robot mover, tracker poller, CAN reader, the CAN
driver's SYNC producer and receiver, the mock encoders).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import threading
import time
import uuid
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.drivers.can_config import default_can_config
from hexcal.drivers.can_encoders import EncoderError, LegEncoders
from hexcal.drivers.ndi import NDITracker, TrackerError, TrackerFrame
from hexcal.mock_hw.can_encoders import MockEncoderNodes
from hexcal.mock_hw.ndi_registry import register_robot, unregister
from hexcal.mock_hw.ndi_tracker import FaultSettings
from hexcal.mock_hw.robot import MockRobot
from hexcal.sim.robots import left_hand


def summary(values_s: list[float] | np.ndarray) -> dict[str, float | int]:
    """n, mean, p1, p50, p99, max (signed), p99_abs and max_abs of ``values_s`` (s), in ms (NaNs
    left out). Both tails are given: the leg errors are negative (late latches)."""
    v = np.asarray(values_s, float) * 1e3
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"n": 0}
    return {
        "n": int(v.size),
        "mean": round(float(np.mean(v)), 4),
        "p1": round(float(np.percentile(v, 1)), 4),
        "p50": round(float(np.percentile(v, 50)), 4),
        "p99": round(float(np.percentile(v, 99)), 4),
        "max": round(float(np.max(v)), 4),
        "p99_abs": round(float(np.percentile(np.abs(v), 99)), 4),
        "max_abs": round(float(np.max(np.abs(v))), 4),
    }


def move_robot(robot: MockRobot, period_s: float, stop: threading.Event, seed: int) -> int:
    """Move the robot to a new random pose near home every ``period_s`` s until ``stop``; the
    number of moves. Steps of a few mm and a few tenths of a degree, as a slow calibration
    motion would cover in that time."""
    rng = np.random.default_rng(seed)
    P0, R0 = robot.true_pose()
    moves = 0
    next_t = time.monotonic()
    while not stop.is_set():
        P = P0 + rng.uniform(-5.0, 5.0, 3)
        R = Rotation.from_rotvec(np.radians(rng.uniform(-0.5, 0.5, 3))).as_matrix() @ R0
        robot.move_to(P, R)
        moves += 1
        next_t += period_s
        stop.wait(max(0.0, next_t - time.monotonic()))
    return moves


def read_tracker(
    trk: NDITracker, stop: threading.Event, out: list[tuple[int, float, float, float]]
) -> None:
    """``trk.sample(binary=True)`` until ``stop``; per sample (frame number, t, its stated
    uncertainty, receive time). The frame behind each sample is seen by wrapping poll_binary
    (sample() returns the first new frame it polls)."""
    last: list[TrackerFrame] = []
    poll = trk.poll_binary

    def poll_binary() -> TrackerFrame:
        frame = poll()
        last[:] = [frame]
        return frame

    trk.poll_binary = poll_binary  # type: ignore[method-assign]
    while not stop.is_set():
        s = trk.sample(binary=True)
        f = last[0]
        if s.fault is None and f.frame_number is not None:
            out.append((f.frame_number, s.t, f.timing_uncertainty_s, f.received_at))


def read_legs(
    enc: LegEncoders, stop: threading.Event, out: list[tuple[int, float, bool, float]]
) -> None:
    """``enc.read_set()`` until ``stop``; per set (SYNC counter, t_sync, complete, mean TPDO
    arrival after the SYNC s)."""
    while not stop.is_set():
        rs = enc.read_set(timeout=1.0)
        arrival = rs.arrival[np.isfinite(rs.arrival)]
        after = float(np.mean(arrival) - rs.t_sync) if arrival.size else float("nan")
        out.append((rs.sync_counter, rs.t_sync, rs.complete, after))


def run(args: argparse.Namespace) -> dict[str, Any]:
    name = f"align{uuid.uuid4().hex[:8]}"
    # The mocks' logs hold the ground truth read at the end: long enough for the whole run.
    log_len = int(200 * (args.seconds + 5))
    robot = MockRobot(left_hand(), seed=args.seed, log_len=log_len)
    faults = FaultSettings(delay_s=args.delay_ms * 1e-3, jitter_s=args.jitter_ms * 1e-3)
    rate = args.frame_rate * (1.0 + args.rate_ppm * 1e-6)  # the tracker's clock vs the host's
    device = register_robot(
        name, robot, seed=args.seed, frame_rate_hz=rate, faults=faults, log_len=log_len
    )
    can_cfg = default_can_config(channel=f"hexcal-{name}")
    nodes = MockEncoderNodes(
        robot, can_cfg, jitter_s=args.can_jitter_ms * 1e-3, seed=args.seed, log_len=log_len
    )
    nodes.start()
    stop = threading.Event()
    tracker_rows: list[tuple[int, float, float, float]] = []
    leg_rows: list[tuple[int, float, bool, float]] = []
    errors: list[str] = []
    trk = NDITracker(
        f"ndimock://{name}",
        baudrate=args.baud,
        reset="command",
        frame_rate_hz=args.frame_rate,
        command_delay_spread_s=args.spread_ms * 1e-3,
    )
    enc = LegEncoders(can_cfg)

    def guarded(target, *a) -> None:
        try:
            target(*a)
        except (TrackerError, EncoderError) as exc:  # report it; the other streams go on
            errors.append(f"{target.__name__}: {exc}")

    try:
        trk.connect()
        enc.start(timeout=2.0)
        t_start = time.monotonic()
        threads = [
            threading.Thread(target=guarded, args=(read_tracker, trk, stop, tracker_rows)),
            threading.Thread(target=guarded, args=(read_legs, enc, stop, leg_rows)),
        ]
        moves: list[int] = []
        mover = threading.Thread(
            target=lambda: moves.append(move_robot(robot, args.move_ms * 1e-3, stop, args.seed))
        )
        for t in (*threads, mover):
            t.start()
        stop.wait(args.seconds)
        stop.set()
        for t in (*threads, mover):
            t.join(timeout=5.0)
        clock = trk.clock_stats()
    finally:
        stop.set()
        enc.stop()
        trk.close()
        nodes.stop()
        unregister(name)

    # -- tracker: stamp vs the mock's measurement instant ----------------------------------------
    truth = dict(device.frame_times)
    t_from = t_start + args.warmup
    trk_rows = [r for r in tracker_rows if r[1] >= t_from and r[0] in truth]
    trk_err = np.array([t - truth[n] for n, t, _, _ in trk_rows])
    trk_unc = np.array([u for _, _, u, _ in trk_rows])
    recv_err = np.array([r - truth[n] for n, _, _, r in trk_rows])
    fallback = sum(1 for r in tracker_rows if r[1] < t_from)

    # -- legs: t_sync vs the instant the mock latched the readings of that SYNC ------------------
    latched_at = {id(arr): t for t, arr in robot.encoder_latches}
    latches: dict[int, list[float]] = {}
    for counter, arr in list(nodes.history):
        if id(arr) in latched_at:
            latches.setdefault(counter, []).append(latched_at[id(arr)])
    leg_t, leg_err, leg_after, incomplete = [], [], [], 0
    for counter, t_sync, complete, after in leg_rows:
        if t_sync < t_from:
            continue
        incomplete += not complete
        candidates = latches.get(counter, [])
        if not candidates:
            continue
        t_latch = min(candidates, key=lambda t: abs(t - t_sync))  # the counter wraps at 240
        if abs(t_latch - t_sync) > 0.5:
            continue
        leg_t.append(t_sync)
        leg_err.append(t_sync - t_latch)
        leg_after.append(after)
    leg_t_arr, leg_err_arr = np.array(leg_t), np.array(leg_err)

    # -- pairs: each tracker sample with the leg set stamped nearest -----------------------------
    align, align_recv = [], []
    if leg_t_arr.size:
        order = np.argsort(leg_t_arr)
        leg_t_arr, leg_err_arr = leg_t_arr[order], leg_err_arr[order]
        for stamp, errs, out in ((1, trk_err, align), (3, recv_err, align_recv)):
            for row, e in zip(trk_rows, errs, strict=True):
                t = row[stamp]
                k = int(np.searchsorted(leg_t_arr, t))
                k = min(
                    range(max(k - 1, 0), min(k + 1, len(leg_t_arr) - 1) + 1),
                    key=lambda i: abs(leg_t_arr[i] - t),
                )
                if abs(leg_t_arr[k] - t) <= 0.6 * can_cfg.sync_period_s:
                    out.append(e - leg_err_arr[k])

    return {
        "command": " ".join(sys.argv),
        "config": {
            "seconds": args.seconds,
            "warmup_s": args.warmup,
            "tracker_delay_ms": args.delay_ms,
            "tracker_jitter_ms": args.jitter_ms,
            "tracker_frame_rate_hz": rate,
            "tracker_rate_ppm_vs_host": args.rate_ppm,
            "driver_frame_rate_hz": args.frame_rate,
            "driver_command_delay_spread_ms": args.spread_ms,
            "baud": args.baud,
            "can_jitter_ms": args.can_jitter_ms,
            "can_sync_period_ms": can_cfg.sync_period_s * 1e3,
            "robot_move_every_ms": args.move_ms,
            "robot_moves": moves[0] if moves else 0,
        },
        "tracker": {
            "samples": len(trk_rows),
            "samples_during_warmup": fallback,
            "stamp_error_ms": summary(trk_err),
            "stated_uncertainty_ms": summary(trk_unc),
            "within_stated_uncertainty": float(np.mean(np.abs(trk_err) <= trk_unc + 1e-9))
            if trk_err.size
            else None,
            "receive_error_ms": summary(recv_err),
            "clock": clock,
        },
        "legs": {
            "sets": len(leg_err),
            "incomplete_sets": incomplete,
            "stamp_error_ms": summary(leg_err_arr),
            "tpdo_arrival_after_sync_ms": summary(leg_after),
        },
        "alignment_error_ms": summary(align),
        "alignment_error_if_tracker_stamped_on_receipt_ms": summary(align_recv),
        "notes": [
            "stamp error = stamped time - the mock's true measurement instant; positive: late",
            "legs: t_sync is taken just before the driver sends the SYNC; the mock nodes latch "
            "at the SYNC's bus time (as a CiA 406 encoder latches in hardware), so the error is "
            "the time between taking t_sync and python-can stamping the SYNC on the bus",
            "tracker: stamped from the frame clock; its residual is about half the driver's "
            "assumed command_delay_spread_s, which a real USB link needs and the mock does not",
        ],
        "errors": errors,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="run time, s")
    parser.add_argument("--warmup", type=float, default=2.0, help="left out of the figures, s")
    parser.add_argument("--delay-ms", type=float, default=5.0, help="tracker reply delay")
    parser.add_argument("--jitter-ms", type=float, default=3.0, help="tracker reply jitter")
    parser.add_argument("--can-jitter-ms", type=float, default=2.0, help="TPDO delay U(0, x)")
    parser.add_argument("--move-ms", type=float, default=50.0, help="robot moves every")
    parser.add_argument("--frame-rate", type=float, default=60.0, help="nominal frame rate, Hz")
    parser.add_argument(
        "--rate-ppm", type=float, default=100.0, help="the mock tracker's clock vs the host's"
    )
    parser.add_argument(
        "--spread-ms", type=float, default=0.5, help="driver's command_delay_spread_s, ms"
    )
    parser.add_argument("--baud", type=int, default=115200)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    print(json.dumps(run(args), indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
