"""``hexcal plan``: the reachable poses that would decide between two effects, or resolve one."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hexcal.app.commands.common import (
    POSITIVE_COUNT,
    SEED,
    add_effects_option,
    add_model_option,
    check_outputs,
    load_effects,
    read_inputs,
)

#: The command's name on the command line.
NAME = "plan"


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``plan`` command and its options."""
    p = sub.add_parser(
        NAME,
        help="plan the poses that tell two effects apart (--separate A B) or resolve one "
        "(--resolve EFFECT)",
    )
    p.add_argument(
        "measurements", type=Path, help="measurements.csv (docs/formats.md) or a session file"
    )
    p.add_argument("--robot", type=Path, help="robot.json (a session file carries its own)")
    add_model_option(p)
    p.add_argument("--instruments", type=Path, help="instruments.json: the noise of the poses")
    p.add_argument(
        "--add", nargs="+", metavar="EFFECT", help="effects already in the model", default=()
    )
    add_effects_option(p)
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument(
        "--separate",
        nargs=2,
        metavar=("A", "B"),
        help="two hypotheses to tell apart: effect names, or 'geometry' for the model as it is",
    )
    what.add_argument("--resolve", metavar="EFFECT", help="an effect whose parameters to resolve")
    p.add_argument("--poses", type=POSITIVE_COUNT, default=12, help="how many poses (default 12)")
    p.add_argument(
        "--wait",
        type=float,
        metavar="S",
        help="s to wait after the session's last pose before the first planned one (default: "
        "the plan chooses, up to --max-wait, where the time separates the hypotheses)",
    )
    p.add_argument(
        "--max-wait",
        type=float,
        metavar="S",
        help="the longest wait the plan may ask for, s (default: as long as the session took)",
    )
    p.add_argument(
        "--temperature",
        type=float,
        metavar="C",
        help="°C the lab will hold while recording the plan (default: the session's last)",
    )
    p.add_argument(
        "--can-hold",
        type=float,
        nargs=2,
        metavar=("LOW", "HIGH"),
        help="°C range the lab can hold the rig at (a climate-controlled room or chamber): the "
        "plan then chooses the temperature too, reached no faster than the session's changed",
    )
    p.add_argument("--seed", type=SEED, default=0, help="the random candidate poses' seed")
    p.add_argument("--out", type=Path, required=True, help="the planned poses (CSV)")
    p.add_argument("--force", action="store_true", help="replace an existing --out file")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from hexcal.app.workflow import refuse_overwrite
    from hexcal.io import json_out
    from hexcal.io.measurements import write_measurements
    from hexcal.vocabulary import ModelKind

    check_outputs((args.out, "plan.csv"))
    load_effects(args)
    inp = read_inputs(args)
    refuse_overwrite(args.out, inp, args.force)
    separate = tuple(args.separate) if args.separate else None
    from hexcal.diagnosis.plan import When

    for name in ("wait", "max_wait"):
        if getattr(args, name) is not None and getattr(args, name) < 0:
            raise SystemExit(f"hexcal plan: --{name.replace('_', '-')} must be at least 0 s")
    if args.temperature is not None and args.can_hold is not None:
        raise SystemExit("hexcal plan: --temperature or --can-hold, not both")
    held = None if args.can_hold is None else (args.can_hold[0], args.can_hold[1])
    when = When(args.wait, args.max_wait, args.temperature, held)
    plan = plan_session(
        inp, ModelKind(args.model), args.add, args.poses, separate, args.resolve, args.seed, when
    )
    write_measurements(plan.meas, args.out)
    if args.json:
        print(json_out.dumps(plan_dict(plan, args.out), indent=2))
    else:
        print("\n".join(plan_lines(plan)))
        print(f"{len(plan.meas)} poses written to {args.out}")
    return 0


def plan_dict(plan, out: Path) -> dict:
    """The plan's figures as JSON."""
    return {
        "kind": plan.kind,
        "hypotheses": list(plan.hypotheses),
        "poses": len(plan.meas),
        "before": plan.before,
        "planned": plan.planned,
        "planned_sd": plan.planned_sd if plan.kind == "separate" else None,
        "random": plan.random,
        "random_poses_to_match": plan.match,
        "decided_after": plan.decide if plan.kind == "separate" else None,
        "wait_s": plan.wait,
        "temperature_c": None if plan.meas.temperature is None else float(plan.meas.temperature[0]),
        "out": str(out),
        "notes": plan.notes,
    }


def plan_lines(plan) -> list[str]:
    """The plan's figures in words."""
    n = len(plan.meas)
    more = "more than 64×" if plan.match is None else f"{plan.match}"
    if plan.kind == "separate":
        a, b = plan.hypotheses
        lines = [
            f"expected separation of {a} and {b} (the Δχ² between them, whichever is true):",
            f"  the session's poses alone: {plan.before:.1f}",
            f"  with these {n} planned poses: {plan.planned:.1f} ± {plan.planned_sd:.1f}",
            f"  with {n} random reachable poses, recorded as these are: {plan.random:.1f}",
            f"  random reachable poses needed to match the plan: {more}",
            "  decided (ΔBIC and the look-alike margin, 2 standard deviations short): "
            + (
                f"after the first {plan.decide} of them"
                if plan.decide is not None
                else f"not within these {n}"
            ),
        ]
    else:
        (e,) = plan.hypotheses
        lines = [
            f"standard error of {e}'s parameters (geometric mean, their units), the geometry "
            "projected out:",
            f"  the session's poses alone: {plan.before:.3g}",
            f"  with these {n} planned poses: {plan.planned:.3g}",
            f"  with {n} random reachable poses: {plan.random:.3g}",
            f"  random reachable poses needed to match the plan: {more}",
        ]
    return lines + [f"note: {t}" for t in plan.notes]


def plan_session(
    inp: Any,
    model: Any,
    added: Sequence[str],
    n_poses: int,
    separate: tuple[str, str] | None = None,
    resolve: str | None = None,
    seed: int = 0,
    when: Any = None,
) -> Any:
    """The poses that decide (:func:`hexcal.diagnosis.plan.plan_poses`) for a session with
    ``added`` effects in the model (and a calibrated model's own); ``when``: a
    :class:`~hexcal.diagnosis.plan.When` (None: the plan chooses the wait)."""
    import numpy as np

    from hexcal.diagnosis.plan import plan_poses
    from hexcal.estimate.effect_fit import Problem
    from hexcal.vocabulary import ModelKind

    base = ("offset",) if model == ModelKind.M42 else ()
    effects = tuple(dict.fromkeys((*base, *inp.model_effects, *added)))
    problem = Problem.build(inp.meas, inp.design, inp.sigmas)
    rng = np.random.default_rng(seed)
    return plan_poses(problem, effects, n_poses, separate, resolve, rng, when=when)
