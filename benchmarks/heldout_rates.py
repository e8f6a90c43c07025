"""The covariate explorer on a held-out set of effects outside the catalogue
(:mod:`hexcal.sim.foreign_heldout`, written apart from the team's own set): for each case and
seed, the judgement ``benchmarks/verdict_rates.py`` applies to the team's cases — the diagnosis
chain with ``--auto``, whether the explorer's lead names what the error follows, and the
held-out RMS over the floor once the effect file it writes is loaded unedited; beside it,
what Model 42 leaves on the same seed's session with nothing hidden (the level a perfect file
can reach on that seed).

    python benchmarks/heldout_rates.py [--sessions 3] [--jobs 1] [--out docs/heldout_rates.json]
"""

# ruff: noqa: E402  (the BLAS thread count is set before numpy is imported)
from __future__ import annotations

from hexcal.app.cli import single_thread_blas

single_thread_blas()

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from verdict_rates import WITHIN, _explorer

from hexcal.app.workflow import Inputs, diagnose_chain
from hexcal.diagnosis import diagnose
from hexcal.sim.foreign_heldout import HELDOUT, clean_twin, heldout


def run_heldout_case(job: tuple[str, int]) -> dict:
    """One session: the ``--auto`` chain's verdicts, the explorer's lead at its end and the
    ratio once its written file is added; ``right`` when the verdict is ``unexplained``, the
    lead names an accepted covariate and the file brings the error within ``WITHIN``× the
    floor."""
    case, seed = job
    t0 = time.perf_counter()
    c = heldout(case, seed)
    inp = Inputs(c.meas, c.design, c.instruments, "stated", f"{case} {seed}")
    chain = diagnose_chain(inp, 42, auto=True)
    first, last = chain[0], chain[-1]
    out: dict = {
        "case": case,
        "seed": seed,
        "chain": [str(d.verdict) for d in chain],
        "ratio_before": first.fit.cv_rms_mm / first.noise_floor_mm,
    }
    out.update(_explorer(c, last))
    lead = None if last.exploration is None else last.exploration.lead
    out["lead_shape"] = None if lead is None else lead.shape.describe(lead.covariate.unit)
    out["lead_legs"] = None if lead is None else list(lead.shape.legs)
    out["top3"] = (
        []
        if last.exploration is None
        else [(x.covariate.name, x.share) for x in last.exploration.leads[:3]]
    )
    out["right"] = bool(out["right"] and out.get("ratio_after", np.inf) <= WITHIN)
    # the same seed with nothing hidden: how far above the floor Model 42 sits by chance
    twin = clean_twin(seed)
    d = diagnose(twin.meas, twin.design, 42, instruments=twin.instruments)
    out["ratio_clean_twin"] = d.fit.cv_rms_mm / d.noise_floor_mm
    out["seconds"] = time.perf_counter() - t0
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sessions", type=int, default=3)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", default="docs/heldout_rates.json")
    ap.add_argument("--cases", nargs="*", help="only these cases (default: every one)")
    args = ap.parse_args()
    cases = args.cases or list(HELDOUT)
    jobs = [(c, s) for c in cases for s in range(args.sessions)]
    t0 = time.perf_counter()
    rows = []
    with ProcessPoolExecutor(args.jobs) as pool:
        for r in pool.map(run_heldout_case, jobs):
            rows.append(r)
            share = r["lead_share"]
            print(
                f"{r['case']:20s} {r['seed']} lead {r['lead']} "
                f"share {'-' if share is None else f'{share:.2f}'} "
                f"before {r['ratio_before']:.2f} after {r.get('ratio_after', float('nan')):.2f} "
                f"(clean twin {r['ratio_clean_twin']:.2f}) {r['lead_shape']} legs {r['lead_legs']} "
                f"named {r['named_right']} "
                f"right {r['right']} chain {r['chain']}",
                flush=True,
            )
    summary = {
        c: {
            "sessions": len(sel),
            "named_right": float(np.mean([r["named_right"] for r in sel])),
            "within_15pct": float(np.mean([r.get("ratio_after", np.inf) <= WITHIN for r in sel])),
            "right": float(np.mean([r["right"] for r in sel])),
        }
        for c in cases
        if (sel := [r for r in rows if r["case"] == c])
    }
    out = {"seconds": time.perf_counter() - t0, "summary": summary, "rows": rows}
    Path(args.out).write_text(json.dumps(out, indent=1, default=str))
    for c, s in summary.items():
        print(f"{c}: named {100 * s['named_right']:.0f} %, right {100 * s['right']:.0f} %")


if __name__ == "__main__":
    main()
