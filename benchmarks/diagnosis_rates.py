"""Detection rates of `hexcal diagnose` over random simulated sessions.

    python benchmarks/diagnosis_rates.py [--sessions 50] [--jobs 2] [--out docs/diagnosis_rates.json]

For every catalogue effect, sessions with that effect hidden at a realistic size (and at 0.3×
that, near the detection limit); clean sessions; and sessions with a structured effect outside
the catalogue (a local dent in one leg). Geometry, noise realisation and effect sizes are drawn
from each session's seed. Reported: the share of right verdicts, the false-alarm rate on clean
sessions, and, after adding the named effect, the held-out RMS against the noise floor.
"""

from __future__ import annotations

import os

# One BLAS thread per worker: the workers already fill the cores, and BLAS threads on top of
# them oversubscribe the machine (diagnose went from 0.8 s to 7 s when they did).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from hexcal.diagnosis import diagnose
from hexcal.effects.foreign import local_dent
from hexcal.effects.inject import effect_hook, realistic_values
from hexcal.instruments import EncoderNoise, Instruments, TrackerNoise
from hexcal.session_sim import SessionPlan, perturbed_truth, simulate_session
from hexcal.study import left_hand

INST = Instruments(
    tracker=TrackerNoise(position_sigma_mm=0.01, orientation_sigma_deg=0.002),
    encoders=EncoderNoise(reading_sigma_mm=0.002),
)
EFFECTS = ("offset", "gain", "backlash", "thermal", "compliance", "leadscrew")


def session(case: str, seed: int, scale: float = 1.0):
    """(measurements, design, model, expected verdict, dent leg) for one random session."""
    design = left_hand().model_copy(update={"platform_mass_kg": 20.0})
    rng = np.random.default_rng(10_000 + seed)
    plan = SessionPlan(temperature_rise_k=5.0)
    truth = perturbed_truth(design, rng, plan)
    model, hooks, dent_leg = 42, [], None
    if case == "offset":
        model = 36  # the design's offsets are then taken as known: their error is the effect
        design = design.with_geometry(
            design.a, design.b, truth.offsets - scale * (truth.offsets - design.offsets)
        )
    elif case in EFFECTS:
        hooks = [effect_hook(case, realistic_values(case, rng, truth, scale), truth)]
    elif case == "foreign":
        dent_leg = int(rng.integers(1, 7))
        hooks = [
            local_dent(
                dent_leg,
                int(rng.integers(0, 3)),
                float(rng.uniform(0.03, 0.06)),
                np.array(design.home.position),
            )
        ]
    meas, _ = simulate_session(design, seed, plan, effects=hooks, truth=truth)
    expected = {"clean": "none", "foreign": "unexplained"}.get(case, case)
    return meas, design, model, expected, dent_leg


def run_one(args):
    case, seed, scale = args
    meas, design, model, expected, dent_leg = session(case, seed, scale)
    d = diagnose(meas, design, model, instruments=INST)
    out = {
        "case": case,
        "seed": seed,
        "scale": scale,
        "verdict": d.verdict,
        "expected": expected,
        "cv_rms_mm": d.fit.cv_rms_mm,
        "floor_mm": d.noise_floor_mm,
        "where": d.where["summary"],
    }
    if dent_leg is not None:
        out["located"] = (
            bool(d.where["worst_legs"]) and d.where["worst_legs"][0] == f"leg {dent_leg}"
        )
    if d.verdict == expected and case in EFFECTS and scale == 1.0:
        after = diagnose(meas, design, model, add=[d.verdict], instruments=INST, problem=d.problem)
        out["cv_after_mm"] = after.fit.cv_rms_mm
        out["floor_after_mm"] = after.noise_floor_mm
        out["verdict_after"] = after.verdict
    return out


def markdown(summary: dict) -> str:
    """The README's table from a summary."""
    lines = [
        "| hidden in the session | sessions | right verdict | verdicts "
        "| held-out RMS / floor after adding it (median, max) | within 15 % of the floor |",
        "|---|---|---|---|---|---|",
    ]
    for key, s in summary.items():
        verdicts = ", ".join(
            f"{v} {n}" for v, n in sorted(s["verdicts"].items(), key=lambda kv: -kv[1])
        )
        after = (
            f"{s['after_ratio_median']:.3f}, {s['after_ratio_max']:.3f}"
            if "after_ratio_median" in s
            else "—"
        )
        within = f"{100 * s['after_within_15pct']:.0f} %" if "after_within_15pct" in s else "—"
        label = {
            "clean": "nothing (clean)",
            "foreign": "a local dent in one leg (outside the catalogue)",
        }.get(key, f"`{key}`" if "(" not in key else key)
        extra = (
            f"; right leg located in {100 * s['located_right_leg']:.0f} %"
            if "located_right_leg" in s
            else ""
        )
        lines.append(
            f"| {label} | {s['sessions']} | {100 * s['right']:.0f} %{extra} | {verdicts} | {after} | {within} |"
        )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sessions", type=int, default=50)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default="docs/diagnosis_rates.json")
    ap.add_argument("--markdown", metavar="JSON", help="only print the table of an earlier run")
    args = ap.parse_args()
    if args.markdown:
        print(markdown(json.loads(Path(args.markdown).read_text())["summary"]))
        return
    jobs = [(c, s, 1.0) for c in (*EFFECTS, "clean", "foreign") for s in range(args.sessions)]
    jobs += [(c, s, 0.3) for c in EFFECTS for s in range(args.sessions)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(run_one, jobs, chunksize=4))
    summary = {}
    for case in (*EFFECTS, "clean", "foreign"):
        for scale in (1.0, 0.3):
            sel = [r for r in rows if r["case"] == case and r["scale"] == scale]
            if not sel:
                continue
            right = [r["verdict"] == r["expected"] for r in sel]
            key = case if scale == 1.0 else f"{case} (0.3× size)"
            s = {
                "sessions": len(sel),
                "right": float(np.mean(right)),
                "verdicts": {
                    v: sum(r["verdict"] == v for r in sel)
                    for v in sorted({r["verdict"] for r in sel})
                },
            }
            after = [r["cv_after_mm"] / r["floor_after_mm"] for r in sel if "cv_after_mm" in r]
            if after:
                s["after_ratio_median"] = float(np.median(after))
                s["after_ratio_max"] = float(np.max(after))
                s["after_within_15pct"] = float(np.mean(np.array(after) <= 1.15))
                s["none_after_adding"] = float(
                    np.mean([r["verdict_after"] == "none" for r in sel if "verdict_after" in r])
                )
            if case == "foreign":
                s["located_right_leg"] = float(np.mean([r["located"] for r in sel]))
            summary[key] = s
    out = {"seconds": time.perf_counter() - t0, "summary": summary, "rows": rows}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1))
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
