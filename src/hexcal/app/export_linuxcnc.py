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
  k (N = k − 1 unless ``--joints`` maps them otherwise);
- LinuxCNC's world frame is hexcal's measurement frame (the tracker's, as registered to the
  base when the session was recorded); its platform frame is hexcal's (the tracked body's);
- ``genhexkins.screw-lead`` 0: hexcal's model has no strut correction for turning joints, and a
  lead left from another configuration would add one; ``genhexkins.spindle-offset`` 0: it moves
  the z of every base and platform point, which the calibrated points already place.

genhexkins has no per-leg offset, gain or play. Those go to the joints' INI sections, in keys
LinuxCNC documents (docs/src/config/ini-config.adoc, ``[JOINT_<num>]``):

- ``HOME_OFFSET`` — "the joint position of the home switch or index pulse": the strut length
  when the leg reads its home reading, ``offset_k + (1 + g_k)·ρ_home`` (ρ_home 0 unless given:
  hexcal's readings then count from the home switch);
- the scale (``INPUT_SCALE`` by default; ``ENCODER_SCALE``, ``SCALE`` or ``STEP_SCALE`` as the
  configuration uses): counts per machine unit, the configuration's present value divided by
  ``1 + g_k`` — a gain g means the leg moves (1 + g) mm per mm the encoder says;
- ``BACKLASH`` — the play β_k: LinuxCNC adds β/2 to the motor position when the joint moves up
  and subtracts it when it moves down (``src/emc/motion/control.c``), hexcal's backlash term
  (``length = reading + offset − β/2·s``, s the direction of the last move) read backwards;
- ``HOME`` — the strut length at the robot's home pose, and ``[TRAJ] HOME`` that pose in X Y Z A
  B C.

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

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.app.export_keys import UNITS
from hexcal.effects import get_effect
from hexcal.effects.backlash import DEADBAND_MM
from hexcal.errors import RefusedError
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


class ExportRefused(RefusedError, ValueError):
    """The model cannot be put into LinuxCNC's terms; the message says why and what to do."""


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


def rpy_deg(rotation: np.ndarray) -> np.ndarray:
    """(..., 3) A, B, C (degrees) of rotation matrices (..., 3, 3): R = R_z(C) R_y(B) R_x(A)."""
    return Rotation.from_matrix(rotation).as_euler("xyz", degrees=True)


def _check(loaded: object, joints: Sequence[int], scale: Sequence[float] | None) -> CalibratedRobot:
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
    pitch = rpy_deg(Rotation.from_quat(loaded.home.quaternion, scalar_first=True).as_matrix())[1]
    if abs(pitch) > PITCH_LIMIT_DEG:
        raise ExportRefused(
            f"the platform frame is pitched {pitch:.1f}° at home: genhexkins' roll-pitch-yaw A, "
            "B, C is singular at B = ±90°, so its forward kinematics cannot follow it there; "
            "record the session with the platform's tool frame nearer the base frame's axes"
        )
    effects = [e.name for e in loaded.calibration.effects]
    if "gain" in effects and scale is None:
        raise ExportRefused(
            "the model has a gain per leg, which the INI carries in each joint's scale: pass "
            "--scale with the counts per machine unit your INI has now (one value, or six)"
        )
    return loaded


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
    out = []
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


def _values(model: LegModel, effect: str) -> np.ndarray | None:
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
) -> LinuxCNCFiles:
    """The HAL and INI text of the calibrated model ``loaded`` (read from ``source``, whose
    bytes have ``sha256``); see the module docstring. ``scale``: the configuration's present
    counts per machine unit, one or six (leg order); ``home_readings`` (6,) mm: the legs'
    readings at their home switches in hexcal's data (default 0)."""
    cal = _check(loaded, joints, scale)
    model = cal.leg_model()
    per = 1.0 / UNITS[units]
    robot = model.robot
    gain = _values(model, "gain")
    g = np.zeros(6) if gain is None else gain * 1e-6
    play = _values(model, "backlash")
    rho_home = np.zeros(6) if home_readings is None else np.asarray(home_readings, float)
    scales = None if scale is None else np.broadcast_to(np.asarray(scale, float), (6,))
    home = LegModel(robot).home(1)
    home_len = model.geometric(home.position, home.rotation)[0]
    files = LinuxCNCFiles("", "", left_out(model), cal.calibration.model)
    head = _header(cal, source, sha256, joints, units, files.left_out)
    hal = [*head, ""]
    for k in np.argsort(joints):  # joint order
        n = joints[k]
        hal.append(f"# joint {n} = hexcal leg {k + 1}")
        for name, point in (("base", robot.a[k]), ("platform", robot.b[k])):
            for c, v in zip("xyz", point, strict=True):
                hal.append(f"setp genhexkins.{name}.{n}.{c} {per * v:.9f}")
    hal += [
        "",
        "# hexcal's model has no strut correction for turning joints; a lead left from another",
        "# configuration would add one (base-n.N and platform-n.N are then unused)",
        "setp genhexkins.screw-lead 0",
        "# the calibrated points place the world origin and the platform frame already",
        "setp genhexkins.spindle-offset 0",
        "# genhexkins.tool-offset: leave it connected to motion.tooloffset.z (tool length only)",
    ]
    ini = [*head, "", "[TRAJ]"]
    abc = rpy_deg(home.rotation[0])
    xyz = per * home.position[0]
    ini += [
        f"# the robot's home pose (robot.json home): X Y Z in {units}, A B C in degrees",
        "HOME = " + " ".join(f"{v:.6f}" for v in (*xyz, *abc)),
        f"LINEAR_UNITS = {units}",
    ]
    for k in np.argsort(joints):
        n = joints[k]
        ini += [
            "",
            f"[JOINT_{n}]",
            f"# hexcal leg {k + 1}: offset {robot.offsets[k]:.6f} mm, gain {1e6 * g[k]:+.1f} ppm"
            + ("" if play is None else f", play {1000 * play[k]:.1f} µm"),
            "TYPE = LINEAR",
            f"HOME_OFFSET = {per * (robot.offsets[k] + (1 + g[k]) * rho_home[k]):.9f}",
            f"HOME = {per * home_len[k]:.9f}",
        ]
        if scales is not None:
            ini.append(f"{scale_key} = {scales[k] / (1 + g[k]):.15g}")
        if play is not None:
            ini.append(f"BACKLASH = {per * play[k]:.9f}")
    files.hal = "\n".join(hal) + "\n"
    files.ini = "\n".join(ini) + "\n"
    return files


def _header(
    cal: CalibratedRobot,
    source: str,
    sha256: str,
    joints: Sequence[int],
    units: str,
    left: list[LeftOut],
) -> list[str]:
    legs = " ".join(map(str, joints))
    lines = [
        f"hexcal export linuxcnc: {cal.calibration.model} from {source}",
        f"  (SHA-256 {sha256}; calibrated {cal.calibration.provenance.created:%Y-%m-%d %H:%M} UTC)",
        f"units: {units}; angles A, B, C in degrees: roll, pitch, yaw about the fixed x, y, z",
        "  axes, R = Rz(C) Ry(B) Rx(A) (genhexkins' pmRpyMatConvert)",
        "frames: LinuxCNC's world frame is hexcal's measurement frame (the tracker's, as",
        "  registered to the base in the calibration session); its platform frame is the",
        "  tracked platform's; X Y Z is the platform frame's origin",
        f"legs: hexcal's legs 1 2 3 4 5 6 are joints {legs}; a joint is the strut length",
        "  |P + R b − a|, base point a and platform point b (genhexkins.base.N, .platform.N)",
        "offsets, gains and play are in the joints' INI keys (HOME_OFFSET, the scale, BACKLASH):",
        "  genhexkins has none",
    ]
    if any(e.name == "backlash" for e in cal.calibration.effects):
        band = cal.backlash_deadband_mm or DEADBAND_MM
        lines += [
            "BACKLASH: LinuxCNC adds half the play in the direction of the commanded motion;",
            f"  hexcal's model counts a move only beyond its dead band ({1000 * band:.1f} µm): on",
            "  a reversal smaller than that, the two differ by the play",
        ]
    if left:
        lines.append("what LinuxCNC cannot express (the pose error each leaves when ignored, over")
        lines.append(
            f"  the ISO 9283 test cube at the home orientation and tilted ±{TILT_DEG:g}°):"
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
