"""``hexcal predict``: readings → poses, or poses → readings, with the model's effects."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

from hexcal.app.commands.common import add_effects_option, check_outputs, load_effects, number

#: The command's name on the command line.
NAME = "predict"


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``predict`` command and its options."""
    pr = sub.add_parser(
        NAME,
        help="readings → poses, or poses → readings (the compensation), with the model's effects",
    )
    pr.add_argument("model", type=Path, help="calibrated.json or robot.json")
    pr.add_argument(
        "table",
        type=Path,
        help="CSV with rho1..rho6 (mm) to compute poses, or x,y,z (mm),qw,qx,qy,qz to compute "
        "readings; optional t (s), temperature (degC); rows in motion order. With a model that "
        "carries its covariance, U_position_mm and U_orientation_deg (k = 2) are added",
    )
    pr.add_argument(
        "--to", choices=("pose", "readings"), help="what to compute (when the table has both)"
    )
    pr.add_argument(
        "--temperature",
        type=number(float, -273.15, 1000.0),
        help="structure temperature for every row, degC",
    )
    pr.add_argument("--out", type=Path, help="CSV to write (default: standard output)")
    pr.add_argument("--force", action="store_true", help="replace an existing --out file")
    add_effects_option(pr)
    pr.set_defaults(func=run)


def uncertainty_columns(loaded, model, table, to: str, values, temperature) -> np.ndarray | None:
    import numpy as np

    """(N, 2): each row's expanded uncertainty (k = 2) of the pose, position mm and
    orientation degrees, from the model's parameter covariance and its readings' noise (None
    when the model file carries no covariance or no noise)."""
    from scipy.spatial.transform import Rotation

    from hexcal.estimate.model_file import CalibratedRobot
    from hexcal.estimate.predict import Poses
    from hexcal.estimate.predict_table import POSE, READINGS
    from hexcal.estimate.uncertainty import pose_uncertainty

    if not isinstance(loaded, CalibratedRobot):
        return None
    cov, noise = loaded.parameter_covariance(), loaded.calibration.noise
    if cov is None or noise is None:
        return None
    t = table.column("t", required=False)
    temp = table.column("temperature", required=False)
    if temp is None and temperature is not None:
        temp = np.full(len(table.rows), float(temperature))
    if to == "pose":
        readings = np.column_stack([table.column(c) for c in READINGS])
        pose = values
    else:
        readings = values
        pose = np.column_stack([table.column(c) for c in POSE])
    rot = Rotation.from_quat(pose[:, 3:7], scalar_first=True).as_matrix()
    u = pose_uncertainty(
        model, cov, Poses(pose[:, :3], rot), readings, noise.sigma_reading_mm, t, temp
    )
    return np.column_stack([u.position_mm, u.orientation_deg])


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from hexcal.estimate.model_file import CalibratedRobot, leg_model_of, load_model
    from hexcal.estimate.predict_table import direction, predict_table, read_table, write_table
    from hexcal.io.fileio import write_text_atomic

    check_outputs((args.out, "predicted.csv"))
    load_effects(args)
    loaded = load_model(args.model)
    if isinstance(loaded, CalibratedRobot):
        for note in loaded.source_notes(str(args.model)):
            print(f"hexcal: {note}", file=sys.stderr)
    model = leg_model_of(loaded)
    table = read_table(args.table)
    to = direction(table, args.to)
    names, values = predict_table(model, table, to, args.temperature)
    extra = uncertainty_columns(loaded, model, table, to, values, args.temperature)
    if extra is not None:
        names = [*names, "U_position_mm", "U_orientation_deg"]
        values = np.column_stack([values, extra])
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
