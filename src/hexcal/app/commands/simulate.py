"""``hexcal simulate``: write a simulated session (robot, measurements, instruments, truth)."""

from __future__ import annotations

import argparse
from pathlib import Path

from hexcal.app.commands.common import (
    COUNT,
    SEED,
    SESSION_POSES,
    SIGMA,
    add_effects_option,
    check_outputs,
    load_effects,
    number,
    refuse_existing,
)

#: The command's name on the command line.
NAME = "simulate"


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``simulate`` command and its options."""
    m = sub.add_parser(
        NAME, help="write a simulated session (robot, measurements, instruments, truth)"
    )
    m.add_argument(
        "--out",
        type=Path,
        required=True,
        help="directory for robot.json, measurements.csv, instruments.json, truth.json",
    )
    m.add_argument("--force", action="store_true", help="replace those files if they exist")
    m.add_argument("--robot", type=Path, help="design robot.json (default: the paper's Left Hand)")
    m.add_argument(
        "--seed", type=SEED, default=1, help="draws the robot: its true geometry and hidden effect"
    )
    m.add_argument(
        "--pose-seed",
        type=SEED,
        help="draws the poses and the noise (default: --seed); another value with the same "
        "--seed is a second session of the same robot, to validate a calibration on",
    )
    m.add_argument(
        "--n-type-i", help="poses of each Type I (direction-clamped) step", type=COUNT, default=8
    )
    m.add_argument(
        "--n-type-ii",
        help="poses of each Type II (direction-and-length) step",
        type=COUNT,
        default=8,
    )
    m.add_argument(
        "--n-type-iii", help="poses of each Type III (length-clamped) step", type=COUNT, default=8
    )
    m.add_argument(
        "--n-free", help="free poses (no clamp), up to 1,000,000", type=SESSION_POSES, default=40
    )
    m.add_argument("--sigma-p-mm", help="tracker position noise σ, mm", type=SIGMA, default=0.01)
    m.add_argument(
        "--sigma-a-deg", help="tracker orientation noise σ, deg", type=SIGMA, default=0.002
    )
    m.add_argument("--sigma-l-mm", help="encoder reading noise σ, mm", type=SIGMA, default=0.002)
    m.add_argument(
        "--effect",
        metavar="EFFECT",
        help="hide this effect at a realistic size: offset, gain, backlash, thermal, "
        "compliance, leadscrew, drift, ujoint, balljoint, or one loaded with --effects",
    )
    m.add_argument(
        "--effect-values",
        nargs="+",
        type=number(float, -1e12, 1e12),
        metavar="V",
        help="the hidden effect's parameter values, in their units and order (default: drawn "
        "at a realistic size)",
    )
    add_effects_option(m)
    m.add_argument(
        "--effect-scale",
        type=number(float, 0.0, 100.0),
        default=1.0,
        help="multiply the effect's size (0.3: near detection)",
    )
    m.add_argument(
        "--mass-kg",
        type=number(float, 0.0, 1e6, lo_open=True),
        help="platform mass written to robot.json (compliance needs it)",
    )
    m.add_argument(
        "--temperature-rise-k",
        type=number(float, -100.0, 100.0),
        default=1.5,
        help="structure temperature rise over the session, K",
    )
    m.add_argument(
        "--tests",
        nargs="+",
        choices=("iso9283", "iso230-2"),
        default=(),
        help="append these standard tests after the session, driven by a controller running "
        "the design (docs/metrology.md)",
    )
    m.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from hexcal.estimate.model_file import load_robot
    from hexcal.sim.robots import left_hand
    from hexcal.sim.session_sim import SessionPlan, write_session_dir
    from hexcal.sim.simulate import NoiseModel

    load_effects(args)
    design = load_robot(args.robot) if args.robot else left_hand()
    if args.mass_kg is not None:
        design = design.model_copy(update={"platform_mass_kg": args.mass_kg})
    plan = SessionPlan(
        n_type_i=args.n_type_i,
        n_type_ii=args.n_type_ii,
        n_type_iii=args.n_type_iii,
        n_free=args.n_free,
        noise=NoiseModel(args.sigma_p_mm, args.sigma_a_deg, args.sigma_l_mm),
        temperature_rise_k=args.temperature_rise_k,
    )
    values = _effect_values(args, design)
    if args.effect == "compliance" and not design.platform_mass_kg:
        raise ValueError(
            "--effect compliance needs the platform mass: pass --mass-kg (or a robot.json with platform_mass_kg)"
        )
    names = ["robot.json", "measurements.csv", "instruments.json", "truth.json"]
    check_outputs((args.out, "/"))
    refuse_existing(args.out, names, args.force)
    if args.robot and Path(args.robot).resolve() == (Path(args.out) / "robot.json").resolve():
        raise ValueError(f"{args.robot}: this is the robot input; choose another --out")
    out = write_session_dir(
        args.out,
        design,
        args.seed,
        plan,
        args.effect,
        args.effect_scale,
        args.pose_seed,
        values,
        tuple(args.tests),
    )
    hidden = f", hidden effect: {args.effect}" if args.effect else ""
    print(
        f"simulated session written to {out}/ (robot.json, measurements.csv, instruments.json, truth.json{hidden})"
    )
    return 0


def _effect_values(args: argparse.Namespace, design):
    """The hidden effect's values given with --effect-values (None: drawn), checked against
    its parameters; the effect's name checked against the registered ones."""
    import numpy as np

    from hexcal.effects import get_effect

    if args.effect is None:
        if args.effect_values:
            raise ValueError("--effect-values needs --effect: which effect the values are of")
        return None
    specs = get_effect(args.effect).params(design)
    if args.effect_values is None:
        return None
    if len(args.effect_values) != len(specs):
        raise ValueError(
            f"--effect-values: {args.effect} takes {len(specs)} values "
            f"({', '.join(f'{s.name} {s.unit}' for s in specs)}), got {len(args.effect_values)}"
        )
    return np.asarray(args.effect_values, float)
