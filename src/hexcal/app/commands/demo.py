"""``hexcal demo``: a whole calibration on mock hardware, headless, with a scripted operator."""

from __future__ import annotations

import argparse
from pathlib import Path

from hexcal.app.commands.common import (
    FREE_POSES,
    POSES_PER_STEP,
    SECONDS,
    SEED,
    check_outputs,
)

#: The command's name on the command line.
NAME = "demo"


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``demo`` command and its options."""
    dm = sub.add_parser(
        NAME,
        help="a whole calibration on mock hardware, headless, with a scripted operator",
    )
    dm.add_argument("--seed", type=SEED, default=1, help="the simulated robot and its effect")
    dm.add_argument(
        "--rig-seed",
        type=SEED,
        help="the rig's noise and motion (default: --seed); another value with the same --seed "
        "and --effect records a second session of the same robot, to validate on",
    )
    dm.add_argument(
        "--effect",
        choices=("gain", "backlash", "leadscrew"),
        help="the effect the robot hides (default: drawn by the seed)",
    )
    dm.add_argument("--procedure", default="model42-direction-length", help="name or TOML file")
    dm.add_argument(
        "--poses-per-step", type=POSES_PER_STEP, help="instead of the procedure's counts"
    )
    dm.add_argument("--free-poses", type=FREE_POSES, help="instead of the procedure's count")
    dm.add_argument("--window-s", type=SECONDS, default=0.25, help="still window per pose, s")
    dm.add_argument(
        "--session",
        type=Path,
        help="session file to write (must not exist; default: hexcal-demo-<time>.json in the "
        "sessions directory, see hexcal run --sessions)",
    )
    dm.add_argument("--json", action="store_true", help="print one JSON object")
    dm.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from hexcal.app.demo import DemoSettings, run_demo
    from hexcal.io import json_out

    check_outputs((args.session, "session.json"))
    settings = DemoSettings(
        seed=args.seed,
        effect=args.effect,
        procedure=args.procedure,
        poses_per_step=args.poses_per_step,
        free_poses=args.free_poses,
        window_s=args.window_s,
        session_path=args.session,
        rig_seed=args.rig_seed,
    )
    say = (lambda m: None) if args.json else (lambda m: print(m, flush=True))
    result = run_demo(settings, on_event=say)
    if args.json:
        print(json_out.dumps(result, why=json_out.accuracy_reason, indent=2))
        return 0
    from hexcal.app.demo import demo_text

    print(demo_text(result))
    return 0
