"""``hexcal study``: the seed paper's Monte-Carlo study (§4) with the direct forms and refinement."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from hexcal.app.commands.common import (
    POSITIVE_COUNT,
    SEED,
    SIGMA,
    check_outputs,
    number,
    refuse_existing,
)

#: The command's name on the command line.
NAME = "study"


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``study`` command and its options."""
    s = sub.add_parser(
        NAME, help="the seed paper's Monte-Carlo study (§4) with the direct forms and refinement"
    )
    s.add_argument(
        "--trials", type=POSITIVE_COUNT, default=1000, help="Monte-Carlo trials per point"
    )
    s.add_argument(
        "--err-p-mm",
        type=SIGMA,
        default=0.1,
        help="position noise (uniform half-width or sigma), mm",
    )
    s.add_argument("--err-a-deg", type=SIGMA, default=0.01, help="orientation noise, deg")
    s.add_argument("--err-l-mm", type=SIGMA, default=0.1, help="reading noise, mm")
    s.add_argument(
        "--noise",
        choices=("uniform", "gaussian"),
        default="uniform",
        help="noise distribution: uniform (the paper's, ± the --err values) or gaussian (σ)",
    )
    s.add_argument(
        "--stroke-mm",
        type=number(float, 0.0, 10_000.0, lo_open=True),
        default=30.0,
        help="Type I length range, ± mm about home",
    )
    s.add_argument(
        "--tilt-deg",
        type=number(float, 0.0, 90.0),
        default=30.0,
        help="platform rotations, ± deg per axis",
    )
    s.add_argument(
        "--cone-deg",
        type=number(float, 0.0, 90.0),
        default=30.0,
        help="Type III leg-direction cone half-angle, deg",
    )
    s.add_argument(
        "--seed", type=SEED, default=0, help="random seed (the same seed, the same study)"
    )
    s.add_argument(
        "--out", default="study-out", help="directory for study.csv, study.json and the PNGs"
    )
    s.add_argument(
        "--independent",
        action="store_true",
        help="a new pose set for every N and trial, as the paper drew them (default: nested "
        "sets, each trial's first N poses of one set of the largest N; docs/methods.md)",
    )
    s.add_argument("--no-plots", action="store_true", help="write the tables only")
    s.add_argument("--force", action="store_true", help="replace the files of an earlier run")
    s.add_argument("--json", action="store_true", help="print the JSON on stdout too")
    s.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import json

    from hexcal.app.progress import progress, wanted
    from hexcal.io import json_out
    from hexcal.io.fileio import new_folder, write_text_atomic
    from hexcal.sim.simulate import PoseRanges
    from hexcal.sim.study import (
        SWEEPS,
        StudyConfig,
        efficiency_table,
        factor_table,
        run_study,
        to_json,
        write_csv,
        write_plots,
    )

    cfg = StudyConfig(
        trials=args.trials,
        err_p_mm=args.err_p_mm,
        err_a_deg=args.err_a_deg,
        err_l_mm=args.err_l_mm,
        noise=args.noise,
        seed=args.seed,
        nested=not args.independent,
        ranges=PoseRanges(stroke_mm=args.stroke_mm, tilt_deg=args.tilt_deg, cone_deg=args.cone_deg),
    )
    check_outputs((args.out, "/"))
    refuse_existing(Path(args.out), ["study.csv", "study.json"], args.force)
    t0 = time.perf_counter()
    with progress(wanted(args.json)) as bar:
        bar.stage(f"the study: {cfg.trials} trials per point, pose-set sweeps", total=SWEEPS)
        result = run_study(cfg, on_sweep=bar.advance)
        elapsed = time.perf_counter() - t0
        with new_folder(args.out) as out:  # removed again if it was made and stays empty
            write_csv(result, out / "study.csv")
            # Strict JSON, whatever the study's own writer lets through (a NaN becomes null).
            text = json_out.dumps(json.loads(to_json(result)), indent=1)
            write_text_atomic(out / "study.json", text)
            if not args.no_plots:
                bar.stage("drawing the plots")
            pngs = [] if args.no_plots else write_plots(result, out)
    if args.json:
        print(text)
    else:
        print(factor_table(result))
        print()
        print(efficiency_table(result))
        print(
            f"\n{cfg.trials} trials per N, {elapsed:.1f} s; wrote {out / 'study.csv'}, {out / 'study.json'}"
            + "".join(f", {p}" for p in pngs)
        )
    return 0
