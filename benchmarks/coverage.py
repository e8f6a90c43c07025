"""Do the poses' stated uncertainties hold? ``position_coverage_95`` over simulated sessions.

    python benchmarks/coverage.py [--sessions 50] [--effect backlash] [--jugglebot]

For each seed: a calibration session of a simulated robot (the Left Hand built off its drawing,
optionally hiding ``--effect``), calibrated as ``hexcal calibrate`` does (Model 42, plus the
effect when one is hidden; the clamp rows; the stated noise) into a calibrated.json carrying its
parameter covariance; then a **second session of the same robot** (new poses and noise, as
``hexcal simulate --pose-seed``) validated as ``hexcal validate --json`` does. Printed as JSON:
each session's ``position_coverage_95``, their mean and spread, and the standard error of the
mean. 0.95 is what stated uncertainties that hold give.

``--jugglebot``: the real robot instead — calibrate on the first half of its 108 poses (Model 42
+ gain, as docs/diagnosis.md does), validate on the second half.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from hexcal.app.commands.validate import _metrology
from hexcal.app.workflow import calibrate_model, read_inputs
from hexcal.estimate.model_validation import validate_model
from hexcal.sim.robots import left_hand
from hexcal.sim.session_sim import SessionPlan, write_session_dir

ROOT = Path(__file__).resolve().parents[1]


def one_session(seed: int, effect: str | None, work: Path) -> dict:
    """Calibrate session ``seed`` and validate on its second session: the coverage."""
    design = left_hand()
    plan = SessionPlan()
    cal_dir = write_session_dir(work / f"cal{seed}", design, seed, plan, effect)
    val_dir = write_session_dir(
        work / f"val{seed}", design, seed, plan, effect, pose_seed=seed + 10_000
    )
    inp = read_inputs(
        cal_dir / "measurements.csv", cal_dir / "robot.json", cal_dir / "instruments.json"
    )
    result = calibrate_model(inp, 42, effects=(effect,) if effect else ())
    val = read_inputs(
        val_dir / "measurements.csv", val_dir / "robot.json", val_dir / "instruments.json"
    )
    model = result.file.leg_model()
    v = validate_model(model, result.name, val.meas, val.sigmas, val.noise_source)
    figures = _metrology(result.file, model, v.model, val.meas, v.noise)
    u = figures.uncertainty
    assert u is not None
    return {
        "seed": seed,
        "coverage": u.coverage_95,
        "chi2_per_dof": v.chi2_per_dof,
        "U_position_mean_mm": float(np.mean(u.position_mm)),
        "position_rms_mm": v.accuracy.position_rms_mm,
    }


def jugglebot(work: Path) -> dict:
    """Model 42 + gain on the Jugglebot's first 54 poses (as recorded), validated on the other
    54 (noise unknown: the model's own, estimated from its residual)."""
    from hexcal.io.log_import import import_log
    from hexcal.io.measurements import write_measurements
    from hexcal.model.noise import NoiseSigmas

    meas = import_log(
        ROOT / "examples/jugglebot/108_calibration_poses.csv",
        ROOT / "examples/jugglebot/map.toml",
    )
    half = len(meas) // 2
    write_measurements(meas.subset(slice(0, half)), work / "first.csv")
    write_measurements(meas.subset(slice(half, None)), work / "second.csv")
    robot = ROOT / "examples/jugglebot/design-robot.json"
    result = calibrate_model(read_inputs(work / "first.csv", robot), 42, effects=("gain",))
    model = result.file.leg_model()
    val = read_inputs(work / "second.csv", robot)
    sig = NoiseSigmas.from_instruments(result.file.calibration.noise)
    v = validate_model(model, result.name, val.meas, sig, "the model's own")
    u = _metrology(result.file, model, v.model, val.meas, sig).uncertainty
    assert u is not None
    return {
        "position_coverage_95": u.coverage_95,
        "chi2_per_dof": v.chi2_per_dof,
        "U_position_mean_mm": float(np.mean(u.position_mm)),
        "position_rms_mm": v.accuracy.position_rms_mm,
        "shifted_legs": v.shifted_legs,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=50)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--effect", default=None, help="a catalogue effect the robot hides")
    ap.add_argument("--jugglebot", action="store_true", help="the real robot's second half")
    args = ap.parse_args(argv)
    if args.jugglebot:
        with tempfile.TemporaryDirectory() as tmp:
            print(json.dumps(jugglebot(Path(tmp)), indent=2))
        return 0
    rows = []
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.first_seed, args.first_seed + args.sessions):
            rows.append(one_session(seed, args.effect, Path(tmp)))
            print(json.dumps(rows[-1]), file=sys.stderr)
    cov = np.array([r["coverage"] for r in rows])
    out = {
        "sessions": len(rows),
        "effect": args.effect,
        "position_coverage_95_mean": float(cov.mean()),
        "position_coverage_95_sd": float(cov.std(ddof=1)) if len(cov) > 1 else None,
        "standard_error_of_mean": float(cov.std(ddof=1) / np.sqrt(len(cov)))
        if len(cov) > 1
        else None,
        "min": float(cov.min()),
        "max": float(cov.max()),
        "seconds": round(time.perf_counter() - start, 1),
        "per_session": rows,
    }
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
