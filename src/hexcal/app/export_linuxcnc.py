"""A calibrated model as LinuxCNC configuration: the ``genhexkins`` HAL parameters and the joints'
INI keys (``hexcal export linuxcnc``).

**genhexkins** (LinuxCNC's ``src/emc/kinematics/genhexkins.c``) holds the joint centres as HAL
pins: ``genhexkins.base.N.{x,y,z}``, the base joints in the base (world) frame, and
``genhexkins.platform.N.{x,y,z}``, the platform joints in the platform frame. Its joint N is the
strut length ``|tran + R(A, B, C)·platform.N − base.N|``, with ``R = R_z(C) R_y(B) R_x(A)``
(``pmRpyMatConvert``: roll A, pitch B, yaw C in degrees about the fixed x, y, z axes), and its
world pose X, Y, Z is the platform frame's origin. hexcal's leg k (1..6) joins ``a_k``
(measurement frame) to ``b_k`` (platform frame), length ``|P + R b_k − a_k|``: the same law. So:

- ``genhexkins.base.N`` = ``a_k``, ``genhexkins.platform.N`` = ``b_k`` for N the joint of leg
  k (N = k − 1 unless ``--joints`` maps them otherwise), in the frame written
  (:mod:`hexcal.app.export_frame`: the tracker's as fitted, the drawing's, or a given one);
- ``genhexkins.screw-lead`` 0: hexcal's model has no strut correction for turning joints, and a
  lead left from another configuration would add one; ``genhexkins.spindle-offset`` 0: it moves
  the z of every base and platform point, which the calibrated points already place.

genhexkins has no per-leg offset, gain or play. Those go to the joints' INI sections, in keys
LinuxCNC documents (docs/src/config/ini-config.adoc, ``[JOINT_<num>]``):

- ``HOME_ABSOLUTE_ENCODER`` and ``HOME_OFFSET`` — "the joint position of the home switch or
  index pulse". LinuxCNC's ``src/emc/motion/homing.c`` (HOME_SET_SWITCH_POSITION) sets an
  absolute encoder's joint to its position + HOME_OFFSET, so there HOME_OFFSET = ``offset_k``
  (``length = offset + (1 + g)·reading``) with HOME_ABSOLUTE_ENCODER = 1; an incremental
  encoder's joint is HOME_OFFSET where its switch trips: the strut length at the switch's
  reading, ``offset_k + (1 + g_k)·ρ_switch``, with HOME_ABSOLUTE_ENCODER = 0;
- the scale (``INPUT_SCALE`` by default; ``ENCODER_SCALE``, ``SCALE`` or ``STEP_SCALE`` as the
  configuration uses): counts per machine unit, the configuration's present value divided by
  ``1 + g_k`` — a gain g means the leg moves (1 + g) mm per mm the encoder says;
- ``BACKLASH`` — the play β_k: LinuxCNC adds β/2 to the motor position when the joint moves up
  and subtracts it when it moves down (``src/emc/motion/control.c``), hexcal's backlash term
  (``length = reading + offset − β/2·s``, s the direction of the last move) read backwards;
- ``HOME`` — the strut length at the home pose, and ``[TRAJ] HOME`` that pose in X Y Z A B C,
  in the frame written, checked against what the session recorded
  (:func:`hexcal.app.export_frame.place`).

The files say which model they ship and why (:func:`shipping`): its held-out position RMS
beside its calibration chain's, and what leaving out what LinuxCNC cannot hold costs in the same
measure, on the session's poses.

Thermal expansion, compliance and a lead screw's periodic error depend on the temperature, the
load or the reading's phase: neither genhexkins nor the INI can hold them. The files name each
with its size and the pose error it leaves when ignored, computed over the ISO 9283 test cube
(:mod:`hexcal.model.iso_tests`) at the home orientation and tilted ± :data:`TILT_DEG` about x and
y, and point to ``hexcal predict --to readings`` (or the compensation table), which carries
them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.app.export_frame import ExportRefused, Placement, choose_frame, place
from hexcal.app.export_keys import UNITS
from hexcal.effects import get_effect
from hexcal.effects.backlash import DEADBAND_MM
from hexcal.estimate.model_file import CalibratedRobot
from hexcal.estimate.predict import LegModel
from hexcal.model.iso_tests import iso9283_cube
from hexcal.model.robot import Robot

#: Effects the INI carries (gain → the scale, backlash → BACKLASH); the rest cannot be.
IN_THE_INI = ("gain", "backlash")
#: Tilt of the poses the pose errors of the left-out effects are computed at, degrees.
TILT_DEG = 5.0
#: The temperature the thermal effect's pose error is given at: 10 K from its 20 °C reference.
THERMAL_AT_C = 30.0
#: |B| within this of 90° puts genhexkins' roll-pitch-yaw at its singularity.
PITCH_LIMIT_DEG = 80.0


@dataclass
class LeftOut:
    """An effect the controller cannot hold: its parameters, its largest contribution to a leg
    (mm) and the pose error it leaves when ignored (mm, degrees), over the check poses."""

    name: str
    parameters: str
    leg_mm: float
    position_mm: float
    orientation_deg: float


@dataclass
class LinuxCNCFiles:
    """The two files' text, and what they could not carry."""

    hal: str
    ini: str
    left_out: list[LeftOut] = field(default_factory=list)
    model: str = ""  #: the model's name, e.g. "Model 42 + backlash"
    #: Which model the files ship and why, and what LinuxCNC leaves out costs (header lines)
    shipping: list[str] = field(default_factory=list)
    #: What the command line must say besides the files (each a line)
    warnings: list[str] = field(default_factory=list)
    #: What of an explicit --home lies outside the session's recorded range
    outside: list[str] = field(default_factory=list)


def _check(
    loaded: object,
    joints: Sequence[int],
    scale: Sequence[float] | None,
    encoders: str | None,
    switch_readings: Sequence[float] | None,
) -> CalibratedRobot:
    if not isinstance(loaded, CalibratedRobot):
        raise ExportRefused(
            "this is a plain robot.json, not a calibrated model: calibrate first (hexcal "
            "calibrate --out calibrated.json) and export that"
        )
    if sorted(joints) != list(range(6)):
        raise ExportRefused(
            f"--joints {','.join(map(str, joints))} is not an order of LinuxCNC's joints 0..5: "
            "give each hexcal leg 1..6 its joint number, each joint once (default 0,1,2,3,4,5)"
        )
    if encoders is None and switch_readings is None:
        raise ExportRefused(
            "say how the joints home: --encoders absolute (HOME_ABSOLUTE_ENCODER: the joint is "
            "the encoder's reading plus HOME_OFFSET, hexcal's offset) or --encoders incremental "
            "with --home-readings (the six legs' readings at their home switches in hexcal's data)"
        )
    if encoders == "absolute" and switch_readings is not None:
        raise ExportRefused(
            "--home-readings are the readings at incremental encoders' home switches: absolute "
            "encoders home where they stand (HOME_ABSOLUTE_ENCODER); give one or the other"
        )
    if encoders == "incremental" and switch_readings is None:
        raise ExportRefused(
            "--encoders incremental needs --home-readings: the six legs' readings (mm, in "
            "hexcal's data) where each trips its home switch; HOME_OFFSET is the strut length there"
        )
    effects = [e.name for e in loaded.calibration.effects]
    if "gain" in effects and scale is None:
        raise ExportRefused(
            "the model has a gain per leg, which the INI carries in each joint's scale: pass "
            "--scale with the counts per machine unit your INI has now (one value, or six)"
        )
    return loaded


def _check_pitch(home: np.ndarray) -> None:
    if abs(home[4]) > PITCH_LIMIT_DEG:
        raise ExportRefused(
            f"the platform frame is pitched {home[4]:.1f}° at home: genhexkins' roll-pitch-yaw A, "
            "B, C is singular at B = ±90°, so its forward kinematics cannot follow it there; "
            "record the session with the platform's tool frame nearer the base frame's axes"
        )


def check_poses(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """(P (M, 3) mm, R (M, 3, 3)): the ISO 9283 cube's 5×5×5 grid at the home orientation and
    tilted ± :data:`TILT_DEG` about x and y."""
    cube = iso9283_cube(robot)
    g = np.linspace(-cube.edge / 2, cube.edge / 2, 5)
    pts = cube.centre + np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    tilts = [np.zeros(3)] + [s * np.radians(TILT_DEG) * e for e in np.eye(3)[:2] for s in (1, -1)]
    rots = [Rotation.from_rotvec(t).as_matrix() @ cube.rotation for t in tilts]
    P = np.concatenate([pts] * len(rots))
    R = np.concatenate([np.broadcast_to(r, (len(pts), 3, 3)) for r in rots])
    return P, R


def left_out(model: LegModel) -> list[LeftOut]:
    """The model's effects the controller cannot hold (see the module docstring)."""
    out: list[LeftOut] = []
    if all(e in IN_THE_INI for e in model.effects):
        return out
    P, R = check_poses(model.robot)
    temp = np.full(len(P), THERMAL_AT_C)
    full = model
    i = 0
    for e in model.effects:
        n = len(get_effect(e).params(model.robot))
        values = model.values[i : i + n]
        i += n
        if e in IN_THE_INI:
            continue
        without = _without(model, e)
        readings = without.readings(P, R, temperature=temp, check_limits=False)
        reached, closed = full.solve_poses(readings, temperature=temp, guess=_poses(P, R))
        dp = np.linalg.norm(reached.position - P, axis=1)[closed]
        rel = np.einsum("nji,njk->nik", R, reached.rotation)[closed]
        ang = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
        data = full.data(readings, P, R, temperature=temp)
        contribution = get_effect(e).contribution(data, values)
        specs = get_effect(e).params(model.robot)
        text = ", ".join(f"{s.name} {v:.4g} {s.unit}" for s, v in zip(specs, values, strict=True))
        out.append(
            LeftOut(e, text, float(np.abs(contribution).max()), float(dp.max()), float(ang.max()))
        )
    return out


def _poses(P: np.ndarray, R: np.ndarray):
    from hexcal.estimate.predict import Poses

    return Poses(P, R)


def _without(model: LegModel, effect: str) -> LegModel:
    keep: list[str] = []
    values: list[float] = []
    i = 0
    for e in model.effects:
        n = len(get_effect(e).params(model.robot))
        if e != effect:
            keep.append(e)
            values.extend(model.values[i : i + n])
        i += n
    return LegModel(model.robot, tuple(keep), np.array(values))


def values_of(model: LegModel, effect: str) -> np.ndarray | None:
    i = 0
    for e in model.effects:
        n = len(get_effect(e).params(model.robot))
        if e == effect:
            return model.values[i : i + n]
        i += n
    return None


def export_linuxcnc(
    loaded: object,
    source: str,
    sha256: str,
    joints: Sequence[int] = (0, 1, 2, 3, 4, 5),
    scale: Sequence[float] | None = None,
    scale_key: str = "INPUT_SCALE",
    home_readings: Sequence[float] | None = None,
    units: str = "mm",
    encoders: str | None = None,
    base_frame: str | list[float] = "tracker",
    drawing: tuple[Robot, str] | None = None,
    session: tuple[Any, str] | None = None,
    home: list[float] | None = None,
) -> LinuxCNCFiles:
    """The HAL and INI text of the calibrated model ``loaded`` (read from ``source``, whose
    bytes have ``sha256``); see the module docstring. ``scale``: the configuration's present
    counts per machine unit, one or six (leg order); ``encoders``: ``absolute`` or
    ``incremental`` (then ``home_readings`` (6,) mm: the legs' readings at their home switches
    in hexcal's data); ``base_frame``: ``tracker``, ``drawing`` or X, Y, Z, A, B, C
    (:mod:`hexcal.app.export_frame`); ``drawing``: (robot.json, its name); ``session``: (the
    measurement table it was calibrated on, its name); ``home``: X, Y, Z mm, A, B, C degrees in
    the frame written."""
    cal = _check(loaded, joints, scale, encoders, home_readings)
    model = cal.leg_model()
    gain = values_of(model, "gain")
    frame = choose_frame(
        base_frame,
        model.robot,
        None if drawing is None else drawing[0],
        "" if drawing is None else drawing[1],
    )
    where = place(model, frame, gain, drawing, session, home)
    _check_pitch(where.home)
    files = LinuxCNCFiles("", "", left_out(_at_home(model, where)), cal.calibration.model)
    files.shipping, files.warnings = shipping(cal, model, files.left_out, session)
    head = _header(cal, source, sha256, joints, units, files, where, home_readings is None)
    files.hal = "\n".join([*head, "", *_hal(model, joints, where, units)]) + "\n"
    switch = None if home_readings is None else np.asarray(home_readings, float)
    ini = _ini(model, joints, where, units, switch, scale, scale_key)
    files.ini = "\n".join([*head, "", *ini]) + "\n"
    files.outside = where.outside
    if where.recorded is None:
        files.warnings.append(
            "the home was not checked against what a session recorded: pass --session"
        )
    return files


def _at_home(model: LegModel, where: Placement) -> LegModel:
    """The model with its home the export's, in the geometry's frame (the check poses of
    :func:`left_out` are about it; robot.json's home is the drawing's frame)."""
    from hexcal.model.robot import Home

    quat = Rotation.from_matrix(where.home_R).as_quat(scalar_first=True)
    home = Home(position=where.home_P.tolist(), quaternion=quat.tolist())
    return LegModel(model.robot.model_copy(update={"home": home}), model.effects, model.values)


def _hal(model: LegModel, joints: Sequence[int], where: Placement, units: str) -> list[str]:
    """genhexkins' setp lines: the points in the frame written."""
    per = 1.0 / UNITS[units]
    a = where.frame.base.apply(model.robot.a)
    b = where.frame.platform.apply(model.robot.b)
    hal = []
    for k in np.argsort(joints):  # joint order
        n = joints[k]
        hal.append(f"# joint {n} = hexcal leg {k + 1}")
        for name, point in (("base", a[k]), ("platform", b[k])):
            for c, v in zip("xyz", point, strict=True):
                hal.append(f"setp genhexkins.{name}.{n}.{c} {per * v:.9f}")
    return hal + [
        "",
        "# hexcal's model has no strut correction for turning joints; a lead left from another",
        "# configuration would add one (base-n.N and platform-n.N are then unused)",
        "setp genhexkins.screw-lead 0",
        "# the calibrated points place the world origin and the platform frame already",
        "setp genhexkins.spindle-offset 0",
        "# genhexkins.tool-offset: leave it connected to motion.tooloffset.z (tool length only)",
    ]


def _ini(
    model: LegModel,
    joints: Sequence[int],
    where: Placement,
    units: str,
    switch: np.ndarray | None,
    scale: Sequence[float] | None,
    scale_key: str,
) -> list[str]:
    """[TRAJ] and the [JOINT_n] sections; ``switch`` (6,) mm: the readings at incremental
    encoders' home switches (None: absolute encoders)."""
    per = 1.0 / UNITS[units]
    robot = model.robot
    gain = values_of(model, "gain")
    g = np.zeros(6) if gain is None else gain * 1e-6
    play = values_of(model, "backlash")
    scales = None if scale is None else np.broadcast_to(np.asarray(scale, float), (6,))
    home_len = model.geometric(where.home_P[None], where.home_R[None])[0]
    ini = [
        "[TRAJ]",
        f"# the robot's home pose, {where.home_source}: X Y Z in {units}, A B C in degrees",
        "HOME = " + " ".join(f"{v:.6f}" for v in (*(per * where.home[:3]), *where.home[3:])),
        f"LINEAR_UNITS = {units}",
    ]
    for k in np.argsort(joints):
        n = joints[k]
        at_switch = 0.0 if switch is None else (1 + g[k]) * switch[k]
        ini += [
            "",
            f"[JOINT_{n}]",
            f"# hexcal leg {k + 1}: offset {robot.offsets[k]:.6f} mm, gain {1e6 * g[k]:+.1f} ppm"
            + ("" if play is None else f", play {1000 * play[k]:.1f} µm")
            + f"; reads {where.home_readings[k]:.3f} mm at HOME",
            "TYPE = LINEAR",
            f"HOME_ABSOLUTE_ENCODER = {0 if switch is not None else 1}",
            f"HOME_OFFSET = {per * (robot.offsets[k] + at_switch):.9f}",
            f"HOME = {per * home_len[k]:.9f}",
        ]
        if scales is not None:
            ini.append(f"{scale_key} = {scales[k] / (1 + g[k]):.15g}")
        if play is not None:
            ini.append(f"BACKLASH = {per * play[k]:.9f}")
    return ini


def session_and_drawing(
    loaded: object, session: Path | None, drawing: Path | None
) -> tuple[tuple[Any, str] | None, tuple[Robot, str] | None]:
    """((the measurement table, its name) of ``session`` — a measurements.csv or a session
    file —, (the drawing, its name)): the drawing is ``drawing`` where given, else the session
    file's robot. A file other than the one the model records it was calibrated from (by
    SHA-256) is refused: its range or its drawing would be another's."""
    from hexcal.estimate.model_file import load_robot, sha256_of
    from hexcal.io.measurements_csv import read_measurements
    from hexcal.procedure import looks_like_session

    recorded = {}
    if isinstance(loaded, CalibratedRobot):
        recorded = {i.role: i for i in loaded.calibration.provenance.inputs}
    meas, robot = None, None
    for role, path in (("measurements", session), ("robot", drawing)):
        rec = recorded.get(role)
        if path is None or rec is None:
            continue
        if sha256_of(path) != rec.sha256:
            raise ExportRefused(
                f"{path} is not the {role} file the model was calibrated with ({rec.name}, "
                f"SHA-256 {rec.sha256[:12]}…): pass that one"
            )
    if session is not None:
        if looks_like_session(session):
            from hexcal.procedure.session import load_session

            s = load_session(session)
            meas, robot = s.measurements(), (s.robot, str(session))
        else:
            meas = read_measurements(session)
    if drawing is not None:
        robot = (load_robot(drawing), str(drawing))
    return (None if meas is None else (meas, str(session))), robot


def shipping(
    cal: CalibratedRobot, model: LegModel, left: list[LeftOut], session: tuple[Any, str] | None
) -> tuple[list[str], list[str]]:
    """Which model the files ship and why (the held-out position RMS of each model of the
    calibration's chain, from calibrated.json), and what LinuxCNC's leaving out ``left`` costs
    in the same measure: the position RMS of the pose computed from the readings against the
    tracker's, on the session's poses, with and without them. Returns (header lines, lines for
    the command line)."""
    name = cal.calibration.model
    held = [a for a in cal.calibration.accuracy if a.heldout and a.position_rms_mm is not None]
    lines: list[str] = []
    warnings: list[str] = []
    mine = next((a for a in held if name == a.model or name.startswith(a.model + " (")), None)
    if mine is not None:
        best = min(held, key=lambda a: a.position_rms_mm or 0.0)
        chain = "; ".join(f"{a.model} {a.position_rms_mm:.4g} mm" for a in held)
        lines.append(f"model: {name}, position RMS {mine.position_rms_mm:.4g} mm on held-out poses")
        if best is mine:
            lines.append(f"  the best of its chain on held-out poses ({chain})")
        else:
            lines.append(
                f"  {best.model} holds better on held-out poses ({chain}): calibrate it and "
                "export that instead"
            )
            warnings.append(lines[-1].strip())
    if not left:
        return lines, warnings
    names = ", ".join(e.name for e in left)
    if session is None:
        for e in left:
            warnings.append(
                f"not in LinuxCNC's terms: {e.name}, up to {1000 * e.position_mm:.1f} µm of pose "
                "error if ignored over the ISO 9283 cube (a largest error on test poses, not "
                "comparable with a held-out RMS: --session gives the same measure)"
            )
        return lines, warnings
    from hexcal.estimate.accuracy import pose_errors

    meas, where = session
    held_model = model
    for e in left:
        held_model = _without(held_model, e.name)
    full, lx = pose_errors(model, meas), pose_errors(held_model, meas)
    both = full.closed & lx.closed
    rms_full = float(np.sqrt(np.mean(full.position_mm[both] ** 2)))
    rms_lx = float(np.sqrt(np.mean(lx.position_mm[both] ** 2)))
    lines += [
        f"as LinuxCNC holds it (without {names}): position RMS {rms_lx:.4g} mm on the",
        f"  {int(both.sum())} poses of {where}, against {rms_full:.4g} mm with {names} (the "
        "same poses, the same measure)",
    ]
    warnings.append(
        f"not in LinuxCNC's terms: {names}: position RMS on the session's {int(both.sum())} "
        f"poses {1000 * rms_full:.1f} → {1000 * rms_lx:.1f} µm if ignored (see the files' header)"
    )
    plain = [a for a in held if not any(e.name in a.model for e in left)]
    better = [a for a in plain if (a.position_rms_mm or 0.0) < rms_lx]
    if better:
        b = min(better, key=lambda a: a.position_rms_mm or 0.0)
        lines += [
            f"  that is worse than {b.model} on held-out poses ({b.position_rms_mm:.4g} mm; an",
            "  in-sample figure is the kinder of the two): for LinuxCNC alone, ship a calibration",
            f"  without {names}",
        ]
        warnings.append(
            f"as LinuxCNC holds it, this model ({rms_lx:.4g} mm in-sample) is worse than "
            f"{b.model} ({b.position_rms_mm:.4g} mm held-out): for LinuxCNC alone, ship a "
            f"calibration without {names}"
        )
    return lines, warnings


def _header(
    cal: CalibratedRobot,
    source: str,
    sha256: str,
    joints: Sequence[int],
    units: str,
    files: LinuxCNCFiles,
    where: Placement,
    absolute: bool,
) -> list[str]:
    legs = " ".join(map(str, joints))
    left = files.left_out
    lines = [
        f"hexcal export linuxcnc: {cal.calibration.model} from {source}",
        f"  (SHA-256 {sha256}; calibrated {cal.calibration.provenance.created:%Y-%m-%d %H:%M} UTC)",
        *files.shipping,
        f"units: {units}; angles A, B, C in degrees: roll, pitch, yaw about the fixed x, y, z",
        "  axes, R = Rz(C) Ry(B) Rx(A) (genhexkins' pmRpyMatConvert)",
    ]
    if units == "mm":
        lines.append(
            "  an INI in inches ([TRAJ] LINEAR_UNITS = inch, as LinuxCNC's hexapod sim's): "
            "export with --units inch"
        )
    lines += [
        *where.frame.text,
        f"legs: hexcal's legs 1 2 3 4 5 6 are joints {legs}; a joint is the strut length",
        "  |P + R b − a|, base point a and platform point b (genhexkins.base.N, .platform.N)",
        "offsets, gains and play are in the joints' INI keys (HOME_OFFSET, the scale, BACKLASH):",
        "  genhexkins has none",
        *_homing(where, absolute),
    ]
    if any(e.name == "backlash" for e in cal.calibration.effects):
        band = cal.backlash_deadband_mm or DEADBAND_MM
        lines += [
            "BACKLASH: LinuxCNC adds half the play in the direction of the commanded motion;",
            f"  hexcal's model counts a move only beyond its dead band ({1000 * band:.1f} µm): on",
            "  a reversal smaller than that, the two differ by the play",
        ]
    if left:
        lines.append("what LinuxCNC cannot express (the largest pose error each leaves when")
        lines.append(
            f"  ignored, over the ISO 9283 test cube at the home orientation and tilted "
            f"±{TILT_DEG:g}°):"
        )
        for e in left:
            at = f" at {THERMAL_AT_C:g} °C" if e.name == "thermal" else ""
            lines.append(
                f"  {e.name}{at}: {e.parameters}; up to {1000 * e.leg_mm:.1f} µm on a leg, "
                f"{1000 * e.position_mm:.1f} µm and {e.orientation_deg:.4f}° on the pose"
            )
        lines.append(
            "  to compensate them, command the readings hexcal computes: hexcal predict "
            "MODEL POSES.csv --to readings, or hexcal export table"
        )
    else:
        lines.append("the model has nothing LinuxCNC cannot express")
    return ["# " + line for line in lines]


def _homing(where: Placement, absolute: bool) -> list[str]:
    """The header's lines on the home pose and on homing."""
    readings = " ".join(f"{v:.2f}" for v in where.home_readings)
    lines = [
        f"home: {where.home_source}; the legs read {readings} mm there",
    ]
    if where.recorded is None:
        lines.append("  (not checked against a session: --session gives the recorded range)")
    elif where.outside:
        lines.append(f"  OUTSIDE what {where.recorded.text()} recorded:")
        lines += [f"    {o}" for o in where.outside]
    else:
        lines.append(f"  within what {where.recorded.text()} recorded")
    if absolute:
        return lines + [
            "homing: absolute encoders, HOME_ABSOLUTE_ENCODER = 1: homing sets each joint to its",
            "  encoder's position + HOME_OFFSET (the leg's offset: hexcal's length = offset +",
            "  reading), then moves to HOME (2: no move; LinuxCNC's homing.c)",
        ]
    return lines + [
        "homing: incremental encoders, HOME_ABSOLUTE_ENCODER = 0: each joint is HOME_OFFSET",
        "  where its home switch trips, the strut length at the switch's reading in hexcal's",
        "  data (--home-readings), then moves to HOME",
    ]
