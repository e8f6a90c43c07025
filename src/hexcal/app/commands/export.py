"""``hexcal export``: a calibrated model in a controller's terms — ``linuxcnc`` (genhexkins' HAL
parameters and the joints' INI keys) or ``table`` (a controller-neutral compensation table)."""

from __future__ import annotations

import argparse
from pathlib import Path

from hexcal.app.commands.common import number, print_help_of, refuse_existing

HAL, INI = "genhexkins.hal", "hexcal_joints.ini"
TABLE_JSON, TABLE_CSV = "compensation.json", "compensation.csv"


def _floats(n_allowed: tuple[int, ...], lo: float, hi: float):
    """An argparse type: comma-separated finite numbers in [lo, hi], as many as allowed."""
    one = number(float, lo, hi)

    def parse(text: str) -> list[float]:
        values = [one(v) for v in text.split(",")]
        if len(values) not in n_allowed:
            want = " or ".join(map(str, n_allowed))
            raise argparse.ArgumentTypeError(f"{text!r}: give {want} comma-separated numbers")
        return values

    return parse


#: The command's name on the command line.
NAME = "export"


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``export`` group: ``linuxcnc``, ``table``."""
    ex = sub.add_parser(NAME, help="a calibrated model in a controller's terms")
    ex_sub = ex.add_subparsers(dest="export_command", metavar="{linuxcnc,table}")
    print_help_of(ex)
    lx = ex_sub.add_parser(
        "linuxcnc", help="genhexkins' HAL parameters and the joints' INI keys (two files)"
    )
    lx.add_argument("model", type=Path, help="calibrated.json")
    lx.add_argument("--out", type=Path, required=True, help=f"directory for {HAL} and {INI}")
    lx.add_argument(
        "--joints",
        type=_joint_order,
        default=[0, 1, 2, 3, 4, 5],
        help="LinuxCNC's joint number of hexcal's legs 1..6, e.g. 0,1,2,3,4,5 (the default)",
    )
    lx.add_argument(
        "--scale",
        type=_floats((1, 6), 1e-9, 1e12),
        help="counts per machine unit the joints' INI has now (one, or six in leg order); "
        "needed when the model has a gain",
    )
    from hexcal.app.export_keys import SCALE_KEYS, UNITS

    lx.add_argument(
        "--scale-key", choices=SCALE_KEYS, default="INPUT_SCALE", help="the INI key of the scale"
    )
    lx.add_argument(
        "--encoders",
        choices=("absolute", "incremental"),
        help="how the joints home: absolute encoders (HOME_ABSOLUTE_ENCODER) or incremental "
        "ones with home switches (then --home-readings)",
    )
    lx.add_argument(
        "--home-readings",
        type=_floats((6,), -1e6, 1e6),
        help="incremental encoders: the six legs' readings (mm) at their home switches in "
        "hexcal's data",
    )
    lx.add_argument(
        "--session",
        type=Path,
        help="the session it was calibrated on (measurements.csv or a session file): the home "
        "is checked against what it recorded",
    )
    lx.add_argument(
        "--drawing",
        type=Path,
        help="the robot's drawing (robot.json): its home pose, and its frames for "
        "--base-frame drawing (a session file carries its own)",
    )
    lx.add_argument(
        "--base-frame",
        type=_frame,
        default="tracker",
        help="the frame to write the geometry in: tracker (as fitted, the default), drawing "
        "(robot.json's, fitted to the calibrated points) or X,Y,Z,A,B,C (the tracker frame's "
        "origin, mm, and axes, degrees, in the base frame)",
    )
    lx.add_argument(
        "--home",
        type=_floats((6,), -1e6, 1e6),
        help="the home pose X,Y,Z (mm),A,B,C (degrees) in the frame written (default: the "
        "drawing's)",
    )
    lx.add_argument(
        "--units",
        choices=tuple(UNITS),
        default="mm",
        help="the machine's units ([TRAJ] LINEAR_UNITS; LinuxCNC's hexapod sim is in inch)",
    )
    lx.add_argument("--force", action="store_true", help="replace the files of an earlier export")
    lx.set_defaults(func=run)
    tb = ex_sub.add_parser(
        "table", help="readings over a pose grid (JSON and CSV), with its interpolation error"
    )
    tb.add_argument("model", type=Path, help="calibrated.json (or a robot.json)")
    tb.add_argument(
        "--out", type=Path, required=True, help=f"directory for {TABLE_JSON}, {TABLE_CSV}"
    )
    tb.add_argument(
        "--nominal",
        type=Path,
        help="the robot.json the controller runs: the table then also gives corrections to it",
    )
    tb.add_argument("--points", type=number(int, 2, 21), default=5, help="values per x, y, z")
    tb.add_argument("--angle-points", type=number(int, 1, 21), default=5, help="values per a, b, c")
    tb.add_argument(
        "--tilt-deg", type=number(float, 0.0, 45.0), default=5.0, help="a, b, c span ± this"
    )
    tb.add_argument(
        "--temperature",
        type=number(float, -273.15, 1000.0),
        default=20.0,
        help="structure temperature for a model with thermal expansion, degC",
    )
    tb.add_argument("--force", action="store_true", help="replace the files of an earlier export")
    tb.set_defaults(func=run)


def _frame(text: str) -> str | list[float]:
    """``--base-frame``: a word, or six numbers X,Y,Z,A,B,C."""
    from hexcal.app.export_frame import FRAME_WORDS

    if text in FRAME_WORDS:
        return text
    try:
        return _floats((6,), -1e6, 1e6)(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: give {' or '.join(FRAME_WORDS)}, or six numbers X,Y,Z,A,B,C (mm, degrees)"
        ) from None


def _joint_order(text: str) -> list[int]:
    values = text.split(",")
    try:
        out = [int(v) for v in values]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: give six joint numbers, e.g. 0,1,2,3,4,5"
        ) from None
    if len(out) != 6:
        raise argparse.ArgumentTypeError(f"{text!r}: give six joint numbers, one per leg")
    return out


def run(args: argparse.Namespace) -> int:
    from hexcal.estimate.model_file import load_model, sha256_of
    from hexcal.io.fileio import write_files_atomic

    loaded = load_model(args.model)
    sha = sha256_of(args.model)
    out = Path(args.out)
    if args.export_command == "linuxcnc":
        refuse_existing(out, [HAL, INI], args.force)  # before any work: --out must be usable
        return _linuxcnc(args, loaded, sha, out)
    from hexcal.app.export_table import build_table, table_csv, table_json
    from hexcal.estimate.model_file import leg_model_of, load_robot, model_label
    from hexcal.estimate.predict import LegModel

    nominal = None if args.nominal is None else LegModel(load_robot(args.nominal))
    table = build_table(
        leg_model_of(loaded),
        nominal,
        args.points,
        args.angle_points,
        args.tilt_deg,
        args.temperature,
    )
    refuse_existing(out, [TABLE_JSON, TABLE_CSV], args.force)
    label = model_label(loaded)
    write_files_atomic(
        out,
        {
            TABLE_JSON: table_json(
                table, label, str(args.model), sha, args.tilt_deg, args.temperature
            ),
            TABLE_CSV: table_csv(table),
        },
    )
    e = table.error["readings"]
    print(
        f"{out / TABLE_JSON} and {out / TABLE_CSV} written: {table.readings.size // 6} poses; "
        f"interpolating the readings errs by up to {1000 * e['reading_max_mm']:.2f} µm "
        f"({1000 * e['position_max_mm']:.2f} µm on the pose)"
    )
    if "corrections" in table.error:
        c = table.error["corrections"]
        print(
            f"  interpolating the corrections to {args.nominal}: up to "
            f"{1000 * c['reading_max_mm']:.3f} µm ({1000 * c['position_max_mm']:.3f} µm on the pose)"
        )
    return 0


def _linuxcnc(args: argparse.Namespace, loaded, sha: str, out: Path) -> int:
    from hexcal.app.export_linuxcnc import export_linuxcnc, session_and_drawing
    from hexcal.io.fileio import write_files_atomic

    session, drawing = session_and_drawing(loaded, args.session, args.drawing)
    files = export_linuxcnc(
        loaded,
        str(args.model),
        sha,
        joints=args.joints,
        scale=args.scale,
        scale_key=args.scale_key,
        home_readings=args.home_readings,
        units=args.units,
        encoders=args.encoders,
        base_frame=args.base_frame,
        drawing=drawing,
        session=session,
        home=args.home,
    )
    refuse_existing(out, [HAL, INI], args.force)
    write_files_atomic(out, {HAL: files.hal, INI: files.ini})  # both or neither, no empty folder
    print(f"{out / HAL} and {out / INI} written ({files.model})")
    for line in dict.fromkeys(x.strip() for x in [*files.shipping[:2], *files.warnings]):
        print(f"  {line}")
    for line in files.outside:
        print(f"  warning: --home lies outside the recorded range: {line}")
    if args.units == "mm":
        print("  LINEAR_UNITS = mm: for an INI in inches (LinuxCNC's hexapod sim), --units inch")
    return 0
