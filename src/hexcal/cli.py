"""The ``hexcal`` command line: calibrate, diagnose, devices, study, simulate, demo, session,
schema.

Errors go to stderr with a non-zero exit status; ``--json`` prints one JSON object on stdout.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

EXIT_INPUT = 2  # bad input: a file, a field or a pose set the user must fix
EXIT_REFUSED = 3  # the data cannot calibrate the robot: more or other poses are needed
EXIT_DRAWING = 4  # the calibration fits but does not match the drawing (swapped legs, …)
EXIT_INTERNAL = 1  # a fault of hexcal's own: the message says how to report it


# -- option types: every number that enters is finite and in range ---------------------------
def _number(kind: type, lo: float | None = None, hi: float | None = None, lo_open: bool = False):
    """An argparse type: ``kind`` (int or float), finite, within [lo, hi] (lo excluded when
    ``lo_open``), with a message naming the allowed range."""
    import math

    def parse(text: str):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{text!r} is not {'an integer' if kind is int else 'a number'}"
            ) from None
        if not math.isfinite(v):
            raise argparse.ArgumentTypeError(f"{text!r} is not finite")
        below = lo is not None and (v <= lo if lo_open else v < lo)
        if below or (hi is not None and v > hi):
            left = "(" if lo_open else "["
            raise argparse.ArgumentTypeError(f"{text} is outside {left}{lo:g}, {hi:g}]")
        return v

    parse.__name__ = kind.__name__
    return parse


COUNT = _number(int, 0, 100_000)  # poses or trials
POSITIVE_COUNT = _number(int, 1, 100_000)
SEED = _number(int, 0, 2**32 - 1)
SIGMA = _number(float, 0.0, 1000.0)
SECONDS = _number(float, 0.0, 60.0, lo_open=True)
POSE_ID = _number(int, 0, 2**53)


def _read_inputs(args: argparse.Namespace):
    """The workflow's inputs from the command's files; a calibrated.json given as --robot
    brings its effects (said on stderr)."""
    from hexcal.workflow import read_inputs

    inp = read_inputs(args.measurements, args.robot, args.instruments)
    for text in inp.notices:
        print(f"hexcal: {text}", file=sys.stderr)
    if getattr(args, "exclude_poses", None):
        inp = inp.without(args.exclude_poses)
    if inp.model_effects and not getattr(args, "json", False):
        print(
            f"hexcal: {args.robot} is a calibrated model: its effects "
            f"({', '.join(inp.model_effects)}) are part of the model",
            file=sys.stderr,
        )
    return inp


def _noise_line(inp, cal) -> str:
    inst = inp.instruments
    if inst is not None:
        return (
            f"{inp.noise_source}: tracker {inst.tracker.position_sigma_mm} mm, "
            f"{inst.tracker.orientation_sigma_deg} deg; encoders {inst.encoders.reading_sigma_mm} mm (1 sigma)"
        )
    line = (
        "estimated from the residual (no --instruments given: relative weights of a typical tracker "
        "and encoder, overall level from chi²/dof)"
    )
    if cal.refinement is not None:
        line += f"; the fit implies {cal.refinement.noise_scale:.2f}× those typical sigmas"
    return line


def _cmd_calibrate(args: argparse.Namespace) -> int:
    import json

    from hexcal.accuracy import accuracy_table
    from hexcal.report_text import calibration_json, calibration_text
    from hexcal.workflow import calibrate_model, refuse_overwrite, save_result

    inp = _read_inputs(args)
    if args.out:
        refuse_overwrite(args.out, inp, args.force)
    result = calibrate_model(
        inp,
        model=args.model,
        effects=tuple(args.add or ()),
        clamps=not args.lengths_only,
        form=args.form,
        do_refine=not args.no_refine,
    )
    cal = result.calibration
    mismatch = _drawing_mismatch(args, inp, cal)
    if args.out and not mismatch:
        save_result(result, args.out, inp, args.force)
    if args.json:
        out = json.loads(calibration_json(cal, str(args.measurements), inp.noise_source))
        out["model_name"] = result.name
        out["effects"] = list(cal.effects)
        out["pose_accuracy"] = [a.to_dict() for a in result.accuracy]
        print(json.dumps(out, indent=2, default=_jsonable))
    else:
        print(calibration_text(cal, inp.label, _noise_line(inp, cal)))
        print(
            "\npose accuracy (the pose the model computes from the readings, against the tracker):"
        )
        print(accuracy_table(result.accuracy))
        if args.out and not mismatch:
            print(f"\ncalibrated model ({result.name}) written to {args.out}")
    return _report_mismatch(mismatch, args)


def _drawing_mismatch(args: argparse.Namespace, inp, cal) -> list[str]:
    """The calibration against the drawing (none with --no-drawing-check)."""
    from hexcal.workflow import check_drawing

    if args.no_drawing_check:
        return []
    return check_drawing(inp, cal, args.drawing_tolerance)


def _report_mismatch(mismatch: list[str], args: argparse.Namespace) -> int:
    if not mismatch:
        return 0
    lines = "\n".join(f"  {m}" for m in mismatch)
    unwritten = f"; {args.out} was not written" if getattr(args, "out", None) else ""
    print(
        f"hexcal: the calibration fits the data but does not match the drawing{unwritten}:\n"
        f"{lines}\nfix the cause and calibrate again; if the drawing itself is wrong, "
        "--drawing-tolerance or --no-drawing-check",
        file=sys.stderr,
    )
    return EXIT_DRAWING


def _jsonable(o):
    import math

    if isinstance(o, float) and not math.isfinite(o):
        return None
    raise TypeError(f"not JSON: {type(o).__name__}")


def _cmd_diagnose(args: argparse.Namespace) -> int:
    import json

    from hexcal.diagnosis.text import before_after_text, diagnosis_text
    from hexcal.workflow import diagnose_chain, model_of, refuse_overwrite, save_result

    inp = _read_inputs(args)
    for out_path in (args.out, args.residuals, args.report):
        if out_path:
            refuse_overwrite(Path(out_path), inp, force=True)
    if args.out:
        refuse_overwrite(args.out, inp, args.force)
    from hexcal.diagnosis.limits import at_limits

    sigma = None if inp.instruments is None else inp.instruments.sigma_reading_mm
    limits = at_limits(inp.meas, inp.design, sigma)
    limit_lines = limits.lines(inp.meas)
    limits_json = limits.to_dict(inp.meas)
    if args.exclude_at_limits and limits.rows:
        inp = inp.without([int(inp.meas.pose_id[r]) for r in limits.rows])
    steps = diagnose_chain(inp, args.model, add=tuple(args.add or ()), auto=args.auto)
    result = model_of(inp, steps, args.model) if args.out else None
    mismatch = []
    if not args.no_drawing_check:
        from hexcal.sanity import check_against_drawing

        ref = steps[0].fit.refinement
        found = check_against_drawing(ref.a, ref.b, inp.design, args.drawing_tolerance)
        mismatch = [f.text for f in found]
    if result is not None and not mismatch:
        save_result(result, args.out, inp, args.force)
    if args.plots:
        from hexcal.diagnosis.plots import before_after, pose_error_map, write_plots

        out = Path(args.plots)
        out.mkdir(parents=True, exist_ok=True)
        paths = write_plots(steps[-1], out)
        paths.append(pose_error_map(steps, out))
        for i in range(1, len(steps)):
            paths.append(before_after(steps[i - 1], steps[i], out, name=f"before_after_{i}.png"))
    if args.residuals:
        from hexcal.fileio import write_text_atomic

        write_text_atomic(args.residuals, steps[-1].residual_table())
    if args.report:
        from hexcal.diagnosis.report import write_report

        write_report(steps, Path(args.report), dict(inp.files), limits=limit_lines)
    if args.json:
        out = steps[-1].to_dict()
        if len(steps) > 1:
            out["steps"] = [
                {
                    "model": d.fit.model_name,
                    "effects": list(d.effects),
                    "cv_rms_mm": d.fit.cv_rms_mm,
                    "cv_blocked_rms_mm": d.fit.cv_blocked_rms_mm,
                    "noise_floor_mm": d.noise_floor_mm,
                    "verdict": d.verdict,
                    "pose_accuracy": None if d.accuracy is None else d.accuracy.to_dict(),
                }
                for d in steps
            ]
        out["at_limits"] = limits_json
        out["at_limits"]["excluded"] = bool(args.exclude_at_limits)
        if result is not None:
            out["written"] = {"path": str(args.out), "model": result.name}
        print(json.dumps(out, indent=2, default=_jsonable))
    else:
        if limit_lines:
            left = "; left out (--exclude-at-limits)" if args.exclude_at_limits else ""
            print(f"poses at the end of a leg's stroke or a joint's limit{left}:")
            print("\n".join(f"  {line}" for line in limit_lines))
            if not args.exclude_at_limits:
                print(
                    "  a leg against its end stop does not follow the model: give leg_range_mm in "
                    "robot.json, or leave these poses out with --exclude-at-limits"
                )
            print()
        for d in steps:
            print(diagnosis_text(d, inp.label))
            print()
        print(before_after_text(steps))
        if args.plots:
            print(f"plots written to {args.plots}/")
        if args.report:
            print(f"report written to {args.report}")
        if result is not None and not mismatch:
            print(f"calibrated model ({result.name}) written to {args.out}")
    return _report_mismatch(mismatch, args)


def _refuse_existing(directory: Path, names: list[str], force: bool) -> None:
    """An output directory whose files would be replaced needs --force."""
    there = [n for n in names if (Path(directory) / n).exists()]
    if there and not force:
        raise ValueError(
            f"{directory}: already holds {', '.join(there)}; pass --force to replace them, or "
            "choose another --out"
        )


def _cmd_validate(args: argparse.Namespace) -> int:
    import json

    from hexcal.model_file import CalibratedRobot, leg_model_of, load_model, model_label
    from hexcal.model_validation import validate_model
    from hexcal.workflow import read_inputs

    loaded = load_model(args.model)
    model = leg_model_of(loaded)
    # The robot of the table is the model's own (a session file's design is not used).
    inp = read_inputs(args.measurements, args.model, args.instruments)
    sig, source = inp.sigmas, inp.noise_source
    if args.instruments is None and isinstance(loaded, CalibratedRobot):
        from hexcal.session import looks_like_session

        noise = loaded.calibration.noise
        if noise is not None and not looks_like_session(args.measurements):
            from hexcal.noise import NoiseSigmas

            sig = NoiseSigmas.from_instruments(noise)
            source = f"the model's own ({args.model}: {loaded.calibration.noise_source})"
    v = validate_model(model, model_label(loaded), inp.meas, sig, source)
    if args.rehome:
        from hexcal.model_validation import estimated_noise, rehome

        sig_r = sig if sig is not None else estimated_noise(model, inp.meas)[0]
        moved, shift = rehome(model, inp.meas, sig_r)
        v.rehomed = validate_model(moved, f"{v.model} re-homed", inp.meas, sig_r, source)
        v.offset_shift_mm = shift
    if args.json:
        print(json.dumps(v.to_dict(), indent=2, default=_jsonable))
    else:
        print(v.text(inp.label))
    return 0


def _cmd_import(args: argparse.Namespace) -> int:
    from hexcal.log_import import import_log
    from hexcal.measurements import write_measurements

    out = Path(args.out)
    if out.resolve() in (Path(args.log).resolve(), Path(args.map).resolve()):
        raise ValueError(f"{out}: this is an input; write the table to another file")
    if out.exists() and not args.force:
        raise ValueError(f"{out}: the file exists; pass --force to replace it")
    meas = import_log(args.log, args.map)
    write_measurements(meas, out)
    print(f"{len(meas)} poses from {args.log} written to {out} (mapping {args.map})")
    return 0


def _cmd_predict(args: argparse.Namespace) -> int:
    from hexcal.fileio import write_text_atomic
    from hexcal.model_file import leg_model_of, load_model
    from hexcal.predict_table import direction, predict_table, read_table, write_table

    model = leg_model_of(load_model(args.model))
    table = read_table(args.table)
    to = direction(table, args.to)
    names, values = predict_table(model, table, to, args.temperature)
    text = write_table(table, names, values)
    if args.out:
        if Path(args.out).resolve() in (Path(args.table).resolve(), Path(args.model).resolve()):
            raise ValueError(f"{args.out}: this is an input; write the output to another file")
        if Path(args.out).exists() and not args.force:
            raise ValueError(f"{args.out}: the file exists; pass --force to replace it")
        write_text_atomic(args.out, text)
        print(f"{len(values)} {'poses' if to == 'pose' else 'readings'} written to {args.out}")
    else:
        sys.stdout.write(text)
    return 0


def _cmd_devices_list(args: argparse.Namespace) -> int:
    from hexcal.devices_check import list_devices

    print("\n".join(list_devices()))
    return 0


def _cmd_can_setup(args: argparse.Namespace) -> int:
    from hexcal.devices import load_devices_config
    from hexcal.drivers.can_lss import LssAddress, LssSetupError, set_node_id

    bus = load_devices_config(args.config).can
    address = None
    if args.serial is not None:
        address = LssAddress(args.vendor, args.product, args.revision, args.serial)
    try:
        res = set_node_id(
            bus, args.node_id, address=address, bitrate=args.bitrate, store=not args.no_store
        )
    except LssSetupError as exc:
        print(f"hexcal devices can-setup: {exc}", file=sys.stderr)
        return 1
    who = f"the device at {res.address}" if res.address else "the only LSS device on the bus"
    print(
        f"{who}: node id 0x{res.old_node_id:02X} → 0x{res.new_node_id:02X}"
        + (f", bit rate {res.bitrate // 1000} kbit/s (after a power cycle)" if res.bitrate else "")
        + ("; stored" if res.stored else "; not stored (lost at power-off)")
    )
    return 0


def _cmd_devices(args: argparse.Namespace) -> int:
    import contextlib

    from hexcal.devices import load_devices_config
    from hexcal.devices_check import check_devices, mock_rig

    if args.mock:
        ctx = mock_rig()
    else:
        if not args.config:
            raise ValueError(
                "hexcal devices check needs --config FILE (the rig's device TOML) or --mock"
            )
        ctx = contextlib.nullcontext(load_devices_config(args.config))
    with ctx as cfg:
        ok, lines = check_devices(cfg)
    print("\n".join(lines))
    return 0 if ok else 1


def _cmd_study(args: argparse.Namespace) -> int:
    from hexcal.simulate import PoseRanges
    from hexcal.study import (
        StudyConfig,
        efficiency_table,
        factor_table,
        plot,
        plot_efficiency,
        run_study,
        to_json,
        write_csv,
    )

    cfg = StudyConfig(
        trials=args.trials,
        err_p_mm=args.err_p_mm,
        err_a_deg=args.err_a_deg,
        err_l_mm=args.err_l_mm,
        noise=args.noise,
        seed=args.seed,
        ranges=PoseRanges(stroke_mm=args.stroke_mm, tilt_deg=args.tilt_deg, cone_deg=args.cone_deg),
    )
    _refuse_existing(Path(args.out), ["study.csv", "study.json"], args.force)
    t0 = time.perf_counter()
    result = run_study(cfg)
    elapsed = time.perf_counter() - t0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(result, out / "study.csv")
    (out / "study.json").write_text(to_json(result), encoding="utf-8")
    pngs = [] if args.no_plots else [*plot(result, out), plot_efficiency(result, out)]
    if args.json:
        print(to_json(result))
    else:
        print(factor_table(result))
        print()
        print(efficiency_table(result))
        print(
            f"\n{cfg.trials} trials per N, {elapsed:.1f} s; wrote {out / 'study.csv'}, {out / 'study.json'}"
            + "".join(f", {p}" for p in pngs)
        )
    return 0


def _cmd_simulate(args: argparse.Namespace) -> int:
    from hexcal.robot import load_robot
    from hexcal.session_sim import SessionPlan, write_session_dir
    from hexcal.simulate import NoiseModel
    from hexcal.study import left_hand

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
    if args.effect == "compliance" and not design.platform_mass_kg:
        raise ValueError(
            "--effect compliance needs the platform mass: pass --mass-kg (or a robot.json with platform_mass_kg)"
        )
    names = ["robot.json", "measurements.csv", "instruments.json", "truth.json"]
    _refuse_existing(args.out, names, args.force)
    if args.robot and Path(args.robot).resolve() == (Path(args.out) / "robot.json").resolve():
        raise ValueError(f"{args.robot}: this is the robot input; choose another --out")
    out = write_session_dir(
        args.out, design, args.seed, plan, args.effect, args.effect_scale, args.pose_seed
    )
    hidden = f", hidden effect: {args.effect}" if args.effect else ""
    print(
        f"simulated session written to {out}/ (robot.json, measurements.csv, instruments.json, truth.json{hidden})"
    )
    return 0


def _cmd_schema(args: argparse.Namespace) -> int:
    from hexcal.session import session_json_schema

    print(session_json_schema(), end="")
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    import json

    from hexcal.demo import DemoSettings, run_demo

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
        print(json.dumps(result, indent=2))
        return 0
    from hexcal.demo import demo_text

    print(demo_text(result))
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from hexcal.tui.app import HexcalApp
    from hexcal.tui.backend import RealBackend, mock_backend

    if args.mock:
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
        from hexcal.devices import load_devices_config
        from hexcal.robot import load_robot

        load_devices_config(args.config)  # refuse a bad file before the UI starts
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
        session_path=args.session,
        procedure=args.procedure,
        poses_per_step=args.poses_per_step,
        free_poses=args.free_poses,
    )
    app.run()
    return 0


def _cmd_session(args: argparse.Namespace) -> int:
    from hexcal.measurements_csv import read_measurements
    from hexcal.robot import load_robot
    from hexcal.session import Session, SessionFile, export_session, load_session

    if args.session_command == "export":
        names = ["measurements.csv", "robot.json", "instruments.json", "calibrated.json"]
        if any((Path(args.out) / n).resolve() == Path(args.session).resolve() for n in names):
            raise ValueError(
                f"{args.session}: the export would replace the session; choose another --out"
            )
        _refuse_existing(args.out, names, args.force)
        written = export_session(load_session(args.session), args.out)
        print(f"exported {args.session} to {Path(args.out)}/: {', '.join(written)}")
        return 0
    inputs = {Path(args.measurements).resolve(), Path(args.robot).resolve()}
    if Path(args.out).resolve() in inputs:
        raise ValueError(f"{args.out}: this is an input; write the session to another file")
    meas = read_measurements(args.measurements)
    sf = SessionFile.create(args.out, Session.from_measurements(meas, load_robot(args.robot)))
    print(f"session {sf.path} created with {len(meas)} poses from {args.measurements}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    from hexcal import __version__

    p = argparse.ArgumentParser(
        prog="hexcal", description="Calibrate Gough-Stewart platforms (units: mm, deg)."
    )
    p.add_argument("--version", action="version", version=f"hexcal {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    c = sub.add_parser("calibrate", help="calibrate Model 36 or 42 from a measurement table")
    c.add_argument(
        "measurements", type=Path, help="measurements.csv (docs/formats.md) or a session file"
    )
    c.add_argument(
        "--robot",
        type=Path,
        help="robot.json: design values, known offsets (a session file carries its own)",
    )
    c.add_argument("--model", type=int, choices=(36, 42), default=42)
    c.add_argument(
        "--instruments", type=Path, help="instruments.json: the noise that weights the fit"
    )
    c.add_argument(
        "--form",
        choices=("paper", "direct"),
        default="paper",
        help="linear seed: the paper's forms or the direct ones",
    )
    c.add_argument("--no-refine", action="store_true", help="stop after the linear methods")
    c.add_argument(
        "--lengths-only",
        action="store_true",
        help="refine from the leg lengths alone, without the clamps' own constraints",
    )
    c.add_argument(
        "--add", nargs="+", metavar="EFFECT", help="catalogue effects to fit with the geometry"
    )
    c.add_argument("--json", action="store_true", help="print one JSON object")
    c.add_argument(
        "--out",
        type=Path,
        help="write the calibrated model here (calibrated.json: the geometry as robot.json has "
        "it, plus every effect with its parameters; docs/formats.md)",
    )
    c.add_argument("--force", action="store_true", help="replace an existing --out file")
    c.add_argument(
        "--exclude-poses",
        nargs="+",
        type=POSE_ID,
        metavar="ID",
        help="leave these pose ids out (e.g. the gross outliers hexcal names)",
    )
    c.add_argument(
        "--drawing-tolerance",
        type=_number(float, 0.0, 10.0, lo_open=True),
        default=0.10,
        help="how far a fitted point may lie from its design point, as a fraction of the "
        "design radius (default 0.10); a leg beyond it, or nearer another leg's design, stops "
        "with exit status 4",
    )
    c.add_argument(
        "--no-drawing-check",
        action="store_true",
        help="do not compare the calibration with the drawing (swapped legs go unnoticed)",
    )
    c.set_defaults(func=_cmd_calibrate)

    d = sub.add_parser(
        "diagnose", help="compare the model with the measurements and find the missing effect"
    )
    d.add_argument(
        "measurements", type=Path, help="measurements.csv (docs/formats.md) or a session file"
    )
    d.add_argument("--robot", type=Path, help="robot.json (a session file carries its own)")
    d.add_argument("--model", type=int, choices=(36, 42), default=42)
    d.add_argument(
        "--instruments", type=Path, help="instruments.json: the noise that sets the floor"
    )
    d.add_argument(
        "--add", nargs="+", metavar="EFFECT", help="catalogue effects already in the model"
    )
    d.add_argument(
        "--auto",
        action="store_true",
        help="add the named effect and go on until the verdict is none",
    )
    d.add_argument("--json", action="store_true", help="print one JSON object")
    d.add_argument("--plots", help="directory for the residual plots (PNG)")
    d.add_argument("--report", help="write one self-contained HTML report here")
    d.add_argument(
        "--residuals", help="write predicted against measured for every pose and leg (CSV)"
    )
    d.add_argument(
        "--out",
        type=Path,
        help="write the last step's calibrated model here (calibrated.json, with its effects)",
    )
    d.add_argument("--force", action="store_true", help="replace an existing --out file")
    d.add_argument(
        "--exclude-at-limits",
        action="store_true",
        help="leave out the poses with a leg at the end of its stroke or a joint at its limit",
    )
    d.add_argument(
        "--exclude-poses",
        nargs="+",
        type=POSE_ID,
        metavar="ID",
        help="leave these pose ids out (e.g. the gross outliers hexcal names)",
    )
    d.add_argument(
        "--drawing-tolerance",
        type=_number(float, 0.0, 10.0, lo_open=True),
        default=0.10,
        help="how far a fitted point may lie from its design point, as a fraction of the "
        "design radius (default 0.10); a leg beyond it, or nearer another leg's design, stops "
        "with exit status 4",
    )
    d.add_argument(
        "--no-drawing-check",
        action="store_true",
        help="do not compare the calibration with the drawing (swapped legs go unnoticed)",
    )
    d.set_defaults(func=_cmd_diagnose)

    v = sub.add_parser(
        "validate",
        help="a model on poses it was not fitted on: leg-length residual, pose error, verdict",
    )
    v.add_argument(
        "model", type=Path, help="calibrated.json, or a plain robot.json (e.g. the drawing)"
    )
    v.add_argument(
        "measurements", type=Path, help="measurements.csv or a session file of other poses"
    )
    v.add_argument(
        "--instruments",
        type=Path,
        help="instruments.json: the noise of these poses (default: a session file's own, else "
        "the model's, else estimated from the poses and said so)",
    )
    v.add_argument("--json", action="store_true", help="print one JSON object")
    v.add_argument(
        "--rehome",
        action="store_true",
        help="also re-estimate the six offsets alone on these poses (after the encoders were "
        "homed again) and report that beside the plain figure",
    )
    v.set_defaults(func=_cmd_validate, robot=None)

    ip = sub.add_parser(
        "import", help="a lab's own log → measurements.csv, by a mapping file of its columns"
    )
    ip.add_argument("log", type=Path, help="the log, CSV with a header row")
    ip.add_argument(
        "--map",
        type=Path,
        required=True,
        help="TOML naming the log's columns, units and conventions (docs/formats.md)",
    )
    ip.add_argument("--out", type=Path, required=True, help="measurements.csv to write")
    ip.add_argument("--force", action="store_true", help="replace an existing --out file")
    ip.set_defaults(func=_cmd_import)

    pr = sub.add_parser(
        "predict",
        help="readings → poses, or poses → readings (the compensation), with the model's effects",
    )
    pr.add_argument("model", type=Path, help="calibrated.json or robot.json")
    pr.add_argument(
        "table",
        type=Path,
        help="CSV with rho1..rho6 (mm) to compute poses, or x,y,z (mm),qw,qx,qy,qz to compute "
        "readings; optional t (s), temperature (degC); rows in motion order",
    )
    pr.add_argument(
        "--to", choices=("pose", "readings"), help="what to compute (when the table has both)"
    )
    pr.add_argument(
        "--temperature",
        type=_number(float, -273.15, 1000.0),
        help="structure temperature for every row, degC",
    )
    pr.add_argument("--out", type=Path, help="CSV to write (default: standard output)")
    pr.add_argument("--force", action="store_true", help="replace an existing --out file")
    pr.set_defaults(func=_cmd_predict)

    dv = sub.add_parser("devices", help="the rig's devices")
    dv_sub = dv.add_subparsers(dest="devices_command", required=True)
    chk = dv_sub.add_parser(
        "check", help="connect to the tracker and the encoders and report what answers"
    )
    chk.add_argument("--config", type=Path, help="the rig's device configuration (TOML)")
    chk.add_argument(
        "--mock", action="store_true", help="check a simulated rig through the real drivers"
    )
    chk.set_defaults(func=_cmd_devices)
    ls = dv_sub.add_parser(
        "list", help="the serial ports and CAN interfaces this computer has (for the rig file)"
    )
    ls.set_defaults(func=_cmd_devices_list)
    lss = dv_sub.add_parser(
        "can-setup",
        help="give an encoder out of its box its node id (and bit rate) over LSS (CiA 305)",
        description="Set a CANopen encoder's node id (and bit rate) over LSS. With --serial the "
        "device is picked by its LSS address (vendor, product, revision from its EDS, serial from "
        "its label); without, exactly one LSS device may be on the bus (plug the encoders in one "
        "at a time).",
    )
    lss.add_argument("--config", type=Path, required=True, help="the rig file (its [can] bus)")
    lss.add_argument("--node-id", type=lambda v: int(v, 0), required=True, help="new node id")
    lss.add_argument("--serial", type=lambda v: int(v, 0), help="serial number (0x1018 sub 4)")
    lss.add_argument("--vendor", type=lambda v: int(v, 0), default=0, help="vendor id (0x1018:1)")
    lss.add_argument("--product", type=lambda v: int(v, 0), default=0x406, help="product code")
    lss.add_argument("--revision", type=lambda v: int(v, 0), default=0x00010000, help="revision")
    lss.add_argument("--bitrate", type=int, help="new bit rate, bit/s (CiA 305 table)")
    lss.add_argument("--no-store", action="store_true", help="do not store in the device")
    lss.set_defaults(func=_cmd_can_setup)

    s = sub.add_parser(
        "study", help="the seed paper's Monte-Carlo study (§4) with the direct forms and refinement"
    )
    s.add_argument("--trials", type=POSITIVE_COUNT, default=1000)
    s.add_argument(
        "--err-p-mm",
        type=SIGMA,
        default=0.1,
        help="position noise (uniform half-width or sigma), mm",
    )
    s.add_argument("--err-a-deg", type=SIGMA, default=0.01, help="orientation noise, deg")
    s.add_argument("--err-l-mm", type=SIGMA, default=0.1, help="reading noise, mm")
    s.add_argument("--noise", choices=("uniform", "gaussian"), default="uniform")
    s.add_argument(
        "--stroke-mm",
        type=_number(float, 0.0, 10_000.0, lo_open=True),
        default=30.0,
        help="Type I length range, ± mm about home",
    )
    s.add_argument(
        "--tilt-deg",
        type=_number(float, 0.0, 90.0),
        default=30.0,
        help="platform rotations, ± deg per axis",
    )
    s.add_argument(
        "--cone-deg",
        type=_number(float, 0.0, 90.0),
        default=30.0,
        help="Type III leg-direction cone half-angle, deg",
    )
    s.add_argument("--seed", type=SEED, default=0)
    s.add_argument(
        "--out", default="study-out", help="directory for study.csv, study.json and the PNGs"
    )
    s.add_argument("--no-plots", action="store_true", help="write the tables only")
    s.add_argument("--force", action="store_true", help="replace the files of an earlier run")
    s.add_argument("--json", action="store_true", help="print the JSON on stdout too")
    s.set_defaults(func=_cmd_study)

    m = sub.add_parser(
        "simulate", help="write a simulated session (robot, measurements, instruments, truth)"
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
    m.add_argument("--n-type-i", type=COUNT, default=8)
    m.add_argument("--n-type-ii", type=COUNT, default=8)
    m.add_argument("--n-type-iii", type=COUNT, default=8)
    m.add_argument("--n-free", type=COUNT, default=40)
    m.add_argument("--sigma-p-mm", type=SIGMA, default=0.01)
    m.add_argument("--sigma-a-deg", type=SIGMA, default=0.002)
    m.add_argument("--sigma-l-mm", type=SIGMA, default=0.002)
    m.add_argument(
        "--effect",
        choices=("offset", "gain", "backlash", "thermal", "compliance", "leadscrew"),
        help="hide this catalogue effect at a realistic size",
    )
    m.add_argument(
        "--effect-scale",
        type=_number(float, 0.0, 100.0),
        default=1.0,
        help="multiply the effect's size (0.3: near detection)",
    )
    m.add_argument(
        "--mass-kg",
        type=_number(float, 0.0, 1e6, lo_open=True),
        help="platform mass written to robot.json (compliance needs it)",
    )
    m.add_argument(
        "--temperature-rise-k",
        type=_number(float, -100.0, 100.0),
        default=1.5,
        help="structure temperature rise over the session, K",
    )
    m.set_defaults(func=_cmd_simulate)

    sc = sub.add_parser("schema", help="print the JSON Schema of the session file")
    sc.set_defaults(func=_cmd_schema)

    dm = sub.add_parser(
        "demo",
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
        "--poses-per-step", type=POSITIVE_COUNT, help="instead of the procedure's counts"
    )
    dm.add_argument("--free-poses", type=COUNT, help="instead of the procedure's count")
    dm.add_argument("--window-s", type=SECONDS, default=0.25, help="still window per pose, s")
    dm.add_argument("--session", type=Path, help="session file to write (must not exist)")
    dm.add_argument("--json", action="store_true", help="print one JSON object")
    dm.set_defaults(func=_cmd_demo)

    rn = sub.add_parser(
        "run",
        help="the operator's text UI: guided clamping and recording, result, diagnosis, export",
    )
    rn.add_argument("--mock", action="store_true", help="simulated devices (no hardware)")
    rn.add_argument("--config", type=Path, help="the rig's device configuration (TOML)")
    rn.add_argument("--robot", type=Path, help="the robot's design, robot.json")
    rn.add_argument("--session", type=Path, help="session file to propose (new or to resume)")
    rn.add_argument(
        "--procedure",
        default="model42-direction-length",
        choices=["model42-direction-length", "model36-direction", "free-validation"],
    )
    rn.add_argument(
        "--poses-per-step", type=POSITIVE_COUNT, help="instead of the procedure's counts"
    )
    rn.add_argument("--free-poses", type=COUNT, help="instead of the procedure's count")
    rn.add_argument("--seed", type=SEED, default=1, help="--mock: the simulated robot")
    rn.add_argument(
        "--effect",
        choices=["gain", "backlash", "leadscrew"],
        help="--mock: the effect the robot hides (default: drawn by the seed)",
    )
    rn.add_argument("--window-s", type=SECONDS, default=0.25, help="--mock: still window, s")
    rn.set_defaults(func=_cmd_run)

    se = sub.add_parser("session", help="export a session file, or make one from a CSV")
    se_sub = se.add_subparsers(dest="session_command", required=True)
    ex = se_sub.add_parser("export", help="measurements.csv, robot.json, calibrated.json")
    ex.add_argument("session", type=Path)
    ex.add_argument("--out", type=Path, required=True, help="directory to write")
    ex.add_argument("--force", action="store_true", help="replace the files of an earlier export")
    ex.set_defaults(func=_cmd_session)
    im = se_sub.add_parser("import", help="a session file from an interchange table")
    im.add_argument("measurements", type=Path)
    im.add_argument("--robot", type=Path, required=True)
    im.add_argument("--out", type=Path, required=True, help="session file to create")
    im.set_defaults(func=_cmd_session)
    return p


def main(argv: list[str] | None = None) -> int:
    import os

    # The problems here are small (a few hundred poses): BLAS threads cost more than they give
    # (measured: diagnose 0.81 s with one thread, 0.91 s with two), and they oversubscribe the
    # cores when several hexcal processes run. The user's own setting wins.
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print("hexcal: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # one error path: a message and an exit status, no traceback
        code, message = error_message(exc)
        print(f"hexcal: {message}", file=sys.stderr)
        if code == EXIT_INTERNAL and os.environ.get("HEXCAL_DEBUG"):
            raise
        return code


def error_message(exc: BaseException) -> tuple[int, str]:
    """(exit status, message) for an exception reaching the command line. hexcal's own errors
    name the file, line, field or device already; library errors are put in words here, so no
    raw library text reaches the user."""
    import numpy as np

    from hexcal.acquisition import PoseRefused
    from hexcal.solvers.whole_robot import CalibrationRefused
    from hexcal.workflow import FitFailed

    if isinstance(exc, (CalibrationRefused, PoseRefused, FitFailed)):
        return EXIT_REFUSED, str(exc)
    if isinstance(exc, np.linalg.LinAlgError):
        return EXIT_REFUSED, (
            "the poses do not determine the geometry (the system to solve is singular); record "
            "poses that move every leg over its stroke and change its direction, or check the "
            "table for repeated or constant columns"
        )
    if isinstance(exc, (RecursionError, MemoryError)):
        return EXIT_INPUT, (
            f"an input is too large or too deeply nested to read ({type(exc).__name__}); check "
            "the files given"
        )
    if isinstance(exc, UnicodeDecodeError):
        return EXIT_INPUT, f"an input is not UTF-8 text (byte {exc.start}); save it as UTF-8"
    if isinstance(exc, OSError):
        where = f"{exc.filename}: " if exc.filename else ""
        return EXIT_INPUT, f"{where}{exc.strerror or exc}"
    if isinstance(exc, ValueError):
        return EXIT_INPUT, str(exc)
    return EXIT_INTERNAL, (
        f"internal error ({type(exc).__name__}: {exc}); this is a fault in hexcal, not in your "
        "data: please report it with the command line (HEXCAL_DEBUG=1 shows the traceback)"
    )


if __name__ == "__main__":
    sys.exit(main())
