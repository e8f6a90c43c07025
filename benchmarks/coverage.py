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
+ gain, as docs/diagnosis.md does), validate on the second half; then (``terms``) poses 55–81
folded in as a second session, as calibrated and re-homed, and the statement judged on poses
82–108.

``--second rehome|effect``: the uncertainty terms beyond the parameters and the readings
(docs/metrology.md). Each seed calibrates Model 42 on a first session, validates a **second
session** and folds it in (the between-session term, as ``hexcal validate --fold-in``), then
judges the statement on a **third session** — never on the second, where the term came from.
``rehome``: the robot hides nothing, and before the second and the third session every leg's
zero moves (N(0, 30 µm) each, independently: a re-home to a switch). ``effect``: the robot hides
backlash the model lacks (Model 42 only; the model-inadequacy term), no re-home. Printed: the
coverage on the third session with the parameters and readings alone, then with each term added,
and each term's size.
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
        "terms": jugglebot_terms(result.file, meas, sig),
    }


def jugglebot_terms(model_file, meas, sig) -> dict:
    """The terms on the Jugglebot: poses 55–81 folded in as a second session (as calibrated,
    and re-homed), the statement judged on poses 82–108 alone, each term's contribution."""
    from hexcal.diagnosis.metrology import of_model_file
    from hexcal.estimate.model_validation import rehome

    model = model_file.leg_model()
    second, third = meas.subset(slice(54, 81)), meas.subset(slice(81, None))
    out = {}
    for how in ("as calibrated", "re-homed"):
        on2, on3 = model, model
        if how == "re-homed":
            on2, on3 = rehome(model, second, sig)[0], rehome(model, third, sig)[0]
        v2 = validate_model(on2, how, second, sig, "the model's own")
        folded = model_file.with_between_session(v2.leg_rms_mm, v2.poses, f"poses 55–81, {how}")
        u = of_model_file(folded, third, sig, leg_model=on3).uncertainty
        assert u is not None
        out[how] = {
            "between_session_mm": folded.session_terms().between_session_mm,
            "between_stated_mm": folded.session_terms().between_stated_mm,
            "poses_82_108": [
                {"with": w, "U_position_mean_mm": m, "position_coverage_95": c}
                for w, m, c in u.contributions
            ],
        }
    return out


#: σ of each leg's zero moving at a re-home, mm.
REHOME_MM = 0.03


def _session(design, truth, plan, pose_seed: int, hooks, label: str):
    """Inputs of one simulated session of ``truth`` (its poses and noise from ``pose_seed``)."""
    from hexcal.app.workflow import Inputs
    from hexcal.model.instruments import EncoderNoise, Instruments, TrackerNoise
    from hexcal.sim.session_sim import simulate_session

    meas, _ = simulate_session(design, pose_seed, plan, effects=hooks, truth=truth)
    inst = Instruments(
        tracker=TrackerNoise(
            position_sigma_mm=plan.noise.sigma_position_mm,
            orientation_sigma_deg=float(np.rad2deg(plan.noise.sigma_orientation_rad)),
        ),
        encoders=EncoderNoise(reading_sigma_mm=plan.noise.sigma_reading_mm),
    )
    return Inputs(meas, design, inst, "stated", label)


def three_sessions(seed: int, scenario: str) -> dict:
    """Calibrate, fold a second session in, judge on a third (see the module docstring)."""
    from hexcal.diagnosis.metrology import of_model_file
    from hexcal.sim.inject import effect_hook, realistic_values
    from hexcal.sim.session_sim import perturbed_truth

    design, plan = left_hand(), SessionPlan()
    rng = np.random.default_rng(seed)
    truth = perturbed_truth(design, rng, plan)
    hooks = []
    if scenario == "effect":
        hooks = [effect_hook("backlash", realistic_values("backlash", rng, truth), truth)]

    def rehomed(k: int):
        if scenario != "rehome":
            return truth
        shift = np.random.default_rng([seed, k]).normal(0.0, REHOME_MM, 6)
        return truth.with_geometry(truth.a, truth.b, truth.offsets + shift)

    first = _session(design, truth, plan, seed, hooks, "first")
    result = calibrate_model(first, 42)
    model_file = result.file
    model = model_file.leg_model()
    second = _session(design, rehomed(2), plan, seed + 10_000, hooks, "second")
    v2 = validate_model(model, result.name, second.meas, second.sigmas, "stated")
    folded = model_file.with_between_session(v2.leg_rms_mm, v2.poses, "second")
    unc = folded.calibration.uncertainty
    assert unc is not None
    terms = folded.session_terms()
    third = _session(design, rehomed(3), plan, seed + 20_000, hooks, "third")
    sig = third.sigmas
    assert sig is not None
    u = of_model_file(folded, third.meas, sig).uncertainty
    assert u is not None
    return {
        "seed": seed,
        "model_inadequacy_mm": terms.model_inadequacy_mm,
        "between_session_mm": terms.between_session_mm,
        "coverage": {w: c for w, _, c in u.contributions},
        "U_position_mean_mm": {w: m for w, m, _ in u.contributions},
    }


def summary_of_terms(rows: list[dict]) -> dict:
    """Mean coverage (and its spread) on the third sessions, term by term."""
    keys = [k.split(" (")[0] for k in rows[0]["coverage"]]
    out = {}
    for i, k in enumerate(keys):
        cov = np.array([list(r["coverage"].values())[i] for r in rows])
        u = np.array([list(r["U_position_mean_mm"].values())[i] for r in rows])
        out[k] = {
            "position_coverage_95_mean": float(cov.mean()),
            "sd": float(cov.std(ddof=1)) if len(cov) > 1 else None,
            "standard_error": float(cov.std(ddof=1) / np.sqrt(len(cov))) if len(cov) > 1 else None,
            "U_position_mean_mm": float(u.mean()),
        }
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=50)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--effect", default=None, help="a catalogue effect the robot hides")
    ap.add_argument("--jugglebot", action="store_true", help="the real robot's second half")
    ap.add_argument(
        "--second",
        choices=("rehome", "effect"),
        help="second and third sessions: a re-home, or an effect the model lacks",
    )
    args = ap.parse_args(argv)
    if args.second:
        start = time.perf_counter()
        rows = []
        for seed in range(args.first_seed, args.first_seed + args.sessions):
            rows.append(three_sessions(seed, args.second))
            print(json.dumps(rows[-1]), file=sys.stderr)
        terms = {
            k: float(np.mean([r[k] or 0.0 for r in rows]))
            for k in ("model_inadequacy_mm", "between_session_mm")
        }
        result = {
            "sessions": len(rows),
            "second": args.second,
            "third_session_coverage": summary_of_terms(rows),
            "mean_terms_mm": terms,
            "seconds": round(time.perf_counter() - start, 1),
        }
        print(json.dumps(result, indent=2))
        return 0
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
