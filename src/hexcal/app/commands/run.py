"""``hexcal run``: the operator's text UI (guided clamping and recording, result, diagnosis, export)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hexcal.app.commands.common import (
    FREE_POSES,
    POSES_PER_STEP,
    SECONDS,
    SEED,
    add_effects_option,
    load_effects,
    number,
)

#: ``--look-alike``'s pairs: hexcal.sim.plan_cases.PAIRS (named here so that --help imports no
#: simulator).
LOOK_ALIKES = {
    "thermal-drift": "thermal vs drift",
    "gain-compliance": "gain vs compliance",
    "ujoint-geometry": "ujoint vs geometry",
}

#: The command's name on the command line.
NAME = "run"


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``run`` command and its options."""
    rn = sub.add_parser(
        NAME,
        help="the operator's text UI: guided clamping and recording, result, diagnosis, export",
    )
    rn.add_argument("--mock", action="store_true", help="simulated devices (no hardware)")
    rn.add_argument("--config", type=Path, help="the rig's device configuration (TOML)")
    rn.add_argument("--robot", type=Path, help="the robot's design, robot.json")
    rn.add_argument("--session", type=Path, help="session file to propose (new or to resume)")
    rn.add_argument(
        "--sessions",
        type=Path,
        help="the sessions directory, listed on the start screen (default: $HEXCAL_SESSIONS, "
        "else the user's data directory, e.g. ~/.local/share/hexcal/sessions)",
    )
    rn.add_argument(
        "--procedure",
        default="model42-direction-length",
        # hexcal.procedure.steps.BUILTIN, named here so that --help imports no pydantic
        choices=[
            "model42-direction-length",
            "model36-direction",
            "free-validation",
            "iso9283",
            "iso230-2",
        ],
        help="the procedure to walk through (procedures/*.toml; default: Model 42 by "
        "direction and length, then length clamping)",
    )
    rn.add_argument(
        "--poses-per-step", type=POSES_PER_STEP, help="instead of the procedure's counts"
    )
    rn.add_argument("--free-poses", type=FREE_POSES, help="instead of the procedure's count")
    rn.add_argument("--seed", type=SEED, default=1, help="--mock: the simulated robot")
    rn.add_argument(
        "--effect",
        choices=["gain", "backlash", "leadscrew"],
        help="--mock: the effect the robot hides (default: drawn by the seed)",
    )
    rn.add_argument(
        "--look-alike",
        choices=list(LOOK_ALIKES),
        help="--mock: a finished session whose poses cannot tell the pair apart, written to the "
        "proposed session file to resume (ctrl+r) and decide with the diagnosis' plan (p); the "
        "mock rig serves the same robot (--seed draws it)",
    )
    rn.add_argument(
        "--scale",
        type=number(float, 0.0, 100.0, lo_open=True),
        default=4.0,
        help="--look-alike: the hidden effect's size, times the look-alike's own (default 4: "
        "--seed 2's thermal-drift session is the worked example's, docs/diagnosis.md)",
    )
    rn.add_argument("--window-s", type=SECONDS, default=0.25, help="--mock: still window, s")
    add_effects_option(rn)
    rn.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from hexcal.tui.app import HexcalApp
    from hexcal.tui.backend import LookAlikeBackend, MockBackend, RealBackend, mock_backend

    backend: MockBackend | RealBackend | LookAlikeBackend
    load_effects(args)
    # The pose counts beyond what a session holds are refused before anything starts.
    from hexcal.app.workflow import procedure_steps
    from hexcal.procedure.steps import load_procedure

    procedure_steps(load_procedure(args.procedure), args.poses_per_step, args.free_poses)
    session = args.session
    if args.look_alike and not args.mock:
        raise SystemExit("hexcal run: --look-alike goes with --mock (a simulated rig)")
    if args.look_alike:
        from hexcal.procedure.sessions_dir import new_session_path, sessions_dir
        from hexcal.tui.backend import look_alike_backend

        backend = look_alike_backend(
            LOOK_ALIKES[args.look_alike], args.seed, args.scale, args.window_s
        )
        session = session or new_session_path(sessions_dir(args.sessions))
        backend.write_session(Path(session), args.procedure)
    elif args.mock:
        backend = mock_backend(args.seed, args.effect, args.window_s)
        if args.robot:
            raise SystemExit("hexcal run: --robot goes with --config (the mock rig has its own)")
    else:
        if not args.config:
            print(
                "hexcal run: give the rig's device configuration (--config rig.toml, see "
                "`hexcal devices check`) and its design (--robot robot.json), or --mock to run "
                "on simulated hardware",
                file=sys.stderr,
            )
            return 2
        from hexcal.acquire.devices import load_devices_config
        from hexcal.effects.plugins import load_files
        from hexcal.estimate.model_file import load_robot

        # Refuse a bad file before the UI starts; its effect files run now, as --effects would.
        load_files(load_devices_config(args.config).effects)
        if not args.robot:
            # A real rig is never the paper's robot: calibrating against the wrong drawing
            # would start from centimetres off, and nothing would say so.
            print(
                "hexcal run: a real rig needs its design: --robot robot.json (the drawing's "
                "attachment points and leg offsets; the format is in docs/formats.md)",
                file=sys.stderr,
            )
            return 2
        design = load_robot(args.robot)
        backend = RealBackend(design, f"rig from {args.config}", config_path=args.config)
    app = HexcalApp(
        backend,
        session_path=session,
        procedure=args.procedure,
        poses_per_step=args.poses_per_step,
        free_poses=args.free_poses,
        sessions=args.sessions,
    )
    app.run()
    return 0
