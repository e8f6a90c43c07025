"""A controller-neutral compensation table (``hexcal export table``): the readings each leg's
encoder must show for the platform to stand at each pose of a grid, for controllers that
interpolate a table rather than run hexcal's model.

**The grid.** Six axes, a regular grid (the specification is in docs/formats.md, "The
compensation table"): X, Y, Z over ISO 9283's test cube (:mod:`hexcal.model.iso_tests`: the
largest cube about home the stroke and joints allow, edges along the measurement frame's axes)
with ``points`` values each, and A, B, C (roll, pitch, yaw about the fixed x, y, z axes, degrees,
as LinuxCNC's genhexkins) over the home orientation's ± ``tilt_deg`` with ``angle_points``
values each. Each row is one node: the pose and the six readings hexcal's model gives for it
(``hexcal predict --to readings``: geometry, offsets, gains, thermal at ``temperature_c``,
compliance, lead screw; backlash left out, its sign is the direction of motion, which a table
cannot know: half the play is the error it leaves). With a ``nominal`` robot.json (the
kinematics the controller runs, e.g. its drawing), the table also gives the correction
``drho_k`` = the reading less the nominal model's, which interpolates far better.

**The interpolation error** is measured, not assumed: at the centre of every cell of the grid
(where multilinear interpolation strays furthest from a curved function) and at
:data:`CHECK_POSES` poses drawn uniformly inside it (seeded, so it is reproducible), the
readings multilinear interpolation of the table gives are compared with the model's own;
stated as the largest and RMS error of a
reading (mm) and the largest pose error they cause (mm, degrees), for the readings and, with a
nominal model, for the corrections.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import RegularGridInterpolator
from scipy.spatial.transform import Rotation

from hexcal.estimate.predict import LegModel, Poses
from hexcal.model.iso_tests import iso9283_cube

FORMAT = "hexcal-compensation-table"
FORMAT_VERSION = 1
#: Poses the interpolation error is measured at.
CHECK_POSES = 2000
#: The default grid: values per position axis, per angle axis, and the tilt, degrees.
POINTS, ANGLE_POINTS, TILT_DEG = 5, 5, 5.0
AXES = ("x", "y", "z", "a", "b", "c")


@dataclass
class Table:
    """The grid's ``axes`` (6 arrays: mm, mm, mm, deg, deg, deg), the readings (…grid…, 6) mm,
    the corrections (same shape; None without a nominal model), whether each node is within
    the stroke and joint limits (…grid…) and the interpolation error (a dict)."""

    axes: list[np.ndarray]
    readings: np.ndarray
    corrections: np.ndarray | None
    feasible: np.ndarray
    error: dict


def grid_axes(model: LegModel, points: int, angle_points: int, tilt_deg: float) -> list[np.ndarray]:
    """The six axes of the grid (module docstring)."""
    cube = iso9283_cube(model.robot)
    h = cube.edge / 2
    pos = [c + np.linspace(-h, h, points) for c in cube.centre]
    home = Rotation.from_matrix(cube.rotation).as_euler("xyz", degrees=True)
    ang = [c + np.linspace(-tilt_deg, tilt_deg, angle_points) for c in home]
    return pos + ang


def _poses(flat: np.ndarray) -> Poses:
    """Poses of (N, 6) rows x, y, z (mm), a, b, c (deg)."""
    return Poses(flat[:, :3], Rotation.from_euler("xyz", flat[:, 3:], degrees=True).as_matrix())


def _readings(model: LegModel, poses: Poses, temperature_c: float) -> np.ndarray:
    """The readings for each pose on its own (no motion history: backlash left out)."""
    t = np.full(len(poses.position), temperature_c)
    if "backlash" in model.effects:
        from hexcal.app.export_linuxcnc import _without

        model = _without(model, "backlash")
    return model.readings(poses.position, poses.rotation, temperature=t, check_limits=False)


def build_table(
    model: LegModel,
    nominal: LegModel | None = None,
    points: int = POINTS,
    angle_points: int = ANGLE_POINTS,
    tilt_deg: float = TILT_DEG,
    temperature_c: float = 20.0,
) -> Table:
    """The table of ``model`` (module docstring)."""
    axes = grid_axes(model, points, angle_points, tilt_deg)
    mesh = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    shape = mesh.shape[:-1]
    flat = mesh.reshape(-1, 6)
    poses = _poses(flat)
    rho = _readings(model, poses, temperature_c)
    corr = None if nominal is None else rho - _readings(nominal, poses, temperature_c)
    feasible = _feasible(model, poses, rho)
    table = Table(
        axes,
        rho.reshape(*shape, 6),
        None if corr is None else corr.reshape(*shape, 6),
        feasible.reshape(shape),
        {},
    )
    table.error = interpolation_error(model, nominal, table, temperature_c)
    return table


def _feasible(model: LegModel, poses: Poses, rho: np.ndarray) -> np.ndarray:
    ok = np.ones(len(rho), bool)
    rng = model.robot.leg_range_mm
    if rng is not None:
        ok &= ((rho >= rng[0]) & (rho <= rng[1])).all(axis=1)
    limit = getattr(model.robot, "joint_limit_deg", None)
    if limit is not None:
        base, plat = model.joint_angles(poses)
        ok &= (np.maximum(base, plat) <= limit).all(axis=1)
    return ok


def interpolation_error(
    model: LegModel, nominal: LegModel | None, table: Table, temperature_c: float
) -> dict:
    """The error multilinear interpolation of ``table`` makes (module docstring)."""
    rng = np.random.default_rng(0)
    lo = np.array([a[0] for a in table.axes])
    hi = np.array([a[-1] for a in table.axes])
    mids = [0.5 * (a[1:] + a[:-1]) if len(a) > 1 else a for a in table.axes]
    centres = np.stack(np.meshgrid(*mids, indexing="ij"), axis=-1).reshape(-1, 6)
    flat = np.concatenate([centres, lo + rng.uniform(size=(CHECK_POSES, 6)) * (hi - lo)])
    poses = _poses(flat)
    exact = _readings(model, poses, temperature_c)
    out = {
        "check_poses": len(flat),
        "where": f"the centre of each of the {len(centres)} cells and {CHECK_POSES} random poses",
        "method": "multilinear in x, y, z, a, b, c",
    }
    interp = RegularGridInterpolator(table.axes, table.readings)(flat)
    out["readings"] = _errors(model, poses, exact, interp, temperature_c)
    if nominal is not None and table.corrections is not None:
        corr = RegularGridInterpolator(table.axes, table.corrections)(flat)
        from_nominal = _readings(nominal, poses, temperature_c) + corr
        out["corrections"] = _errors(model, poses, exact, from_nominal, temperature_c)
    return out


def _errors(model, poses: Poses, exact, approx, temperature_c) -> dict:
    """Reading errors (mm) and the pose errors they cause (mm, deg)."""
    d = approx - exact
    t = np.full(len(d), temperature_c)
    plain = model
    if "backlash" in model.effects:
        from hexcal.app.export_linuxcnc import _without

        plain = _without(model, "backlash")
    reached, closed = plain.solve_poses(approx, temperature=t, guess=poses)
    dp = np.linalg.norm(reached.position - poses.position, axis=1)[closed]
    rel = np.einsum("nji,njk->nik", poses.rotation, reached.rotation)[closed]
    ang = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    return {
        "reading_max_mm": float(np.abs(d).max()),
        "reading_rms_mm": float(np.sqrt(np.mean(d**2))),
        "position_max_mm": float(dp.max()),
        "orientation_max_deg": float(ang.max()),
    }


def table_json(
    table: Table, model_name: str, source: str, sha256: str, tilt_deg: float, temperature_c: float
) -> str:
    """The table as JSON (docs/formats.md, "The compensation table")."""
    data = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "model": model_name,
        "source": {"name": source, "sha256": sha256},
        "units": {
            "x": "mm",
            "y": "mm",
            "z": "mm",
            "a": "deg",
            "b": "deg",
            "c": "deg",
            "readings": "mm",
        },
        "frame": "the measurement frame (the tracker's, as registered to the base); a, b, c: "
        "roll, pitch, yaw about the fixed x, y, z axes, R = Rz(c) Ry(b) Rx(a); x, y, z: the "
        "platform frame's origin",
        "grid": {
            "axes": {k: v.tolist() for k, v in zip(AXES, table.axes, strict=True)},
            "derivation": "x, y, z: ISO 9283's test cube (hexcal.model.iso_tests); a, b, c: the "
            f"home orientation ± {tilt_deg:g}°",
            "order": "row-major: x slowest, c fastest (the CSV's row order)",
        },
        "temperature_c": temperature_c,
        "backlash": "not in the table: its sign is the direction of motion",
        "readings": table.readings.reshape(-1, 6).tolist(),
        "corrections": None
        if table.corrections is None
        else table.corrections.reshape(-1, 6).tolist(),
        "feasible": table.feasible.reshape(-1).astype(int).tolist(),
        "interpolation_error": table.error,
    }
    return json.dumps(data, indent=1) + "\n"


def table_csv(table: Table) -> str:
    """One row per node: x, y, z, a, b, c, rho1..6 (and drho1..6), feasible."""
    mesh = np.stack(np.meshgrid(*table.axes, indexing="ij"), axis=-1).reshape(-1, 6)
    cols = [*AXES, *(f"rho{k}" for k in range(1, 7))]
    parts = [mesh, table.readings.reshape(-1, 6)]
    if table.corrections is not None:
        cols += [f"drho{k}" for k in range(1, 7)]
        parts.append(table.corrections.reshape(-1, 6))
    body = np.concatenate(parts, axis=1)
    ok = table.feasible.reshape(-1)
    lines = [",".join([*cols, "feasible"])]
    lines += [
        ",".join(f"{v:.9f}" for v in row) + f",{int(f)}" for row, f in zip(body, ok, strict=True)
    ]
    return "\n".join(lines) + "\n"
