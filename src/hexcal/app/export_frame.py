"""Where ``hexcal export linuxcnc`` puts the robot: the frame it writes the geometry in, the home
pose in that frame, and what the calibration session recorded (the home is checked against it).

hexcal fits the geometry in the tracker's measurement frame (base points ``a``) and the tracked
body's frame (platform points ``b``). A tracker is seldom registered to the robot's base: the
Jugglebot's motion capture puts its base 36 mm below the capture's origin, tilted 0.8°. LinuxCNC's
world frame is the frame its base points are in, so the export writes one of:

- ``tracker`` (the default): the geometry as fitted, the tracker's frame and the tracked body's;
- ``drawing``: the drawing's base and platform frames, each the best fit (rotation and
  translation, Kabsch: :meth:`scipy.spatial.transform.Rotation.align_vectors`) of the calibrated
  points onto robot.json's; robot.json's home pose is then LinuxCNC's home as drawn;
- a given transform ``X,Y,Z,A,B,C``: the tracker frame's origin (mm) and axes (A, B, C degrees,
  genhexkins' roll-pitch-yaw) in the robot's base frame, ``p_base = R(A,B,C)·p + (X,Y,Z)``; the
  platform frame stays the tracked body's.

A pose (P, R) of the tracked body in the tracker's frame becomes, with the base transform
(R_b, t_b) and the platform transform (R_p, t_p): R' = R_b R R_pᵀ, P' = R_b P + t_b − R' t_p; every
leg length |P + R b − a| is unchanged (:func:`to_frame`).

The home pose is ``--home`` where given, else robot.json's home carried from the drawing's frame
into the one written (which needs the drawing). The joints' home readings follow from it
(``(HOME − offset)/(1 + g)``, what the encoder reads when LinuxCNC's joint is at HOME); the home
pose and each reading are checked against the session's recorded range (:class:`Recorded`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.errors import RefusedError
from hexcal.estimate.predict import LegModel
from hexcal.model.robot import Robot

#: The words ``--base-frame`` takes besides a transform.
FRAME_WORDS = ("tracker", "drawing")
#: A base fit this far from the identity (mm of translation, degrees of rotation: beyond what
#: a drawing's few tenths of a millimetre of error tilt a 100 mm base by) is a tracker
#: frame that is not the base's: the export says so when it writes the tracker's frame.
UNREGISTERED_MM, UNREGISTERED_DEG = 1.0, 0.5


def rpy_deg(rotation: np.ndarray) -> np.ndarray:
    """(..., 3) A, B, C (degrees) of rotation matrices (..., 3, 3): R = R_z(C) R_y(B) R_x(A)."""
    return Rotation.from_matrix(rotation).as_euler("xyz", degrees=True)


def rpy_matrix(abc_deg: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices of A, B, C (degrees, genhexkins' roll-pitch-yaw)."""
    return Rotation.from_euler("xyz", abc_deg, degrees=True).as_matrix()


@dataclass(frozen=True)
class Rigid:
    """x' = rotation · x + translation: rotation (3, 3), translation (3,) mm."""

    rotation: np.ndarray
    translation: np.ndarray

    @classmethod
    def identity(cls) -> Rigid:
        return cls(np.eye(3), np.zeros(3))

    def apply(self, x: np.ndarray) -> np.ndarray:
        """(..., 3) mm → (..., 3) mm."""
        return x @ self.rotation.T + self.translation

    def size(self) -> tuple[float, float]:
        """(translation mm, rotation degrees) of this transform from the identity."""
        angle = np.degrees(Rotation.from_matrix(self.rotation).magnitude())
        return float(np.linalg.norm(self.translation)), float(angle)


def best_fit(source: np.ndarray, target: np.ndarray) -> tuple[Rigid, float]:
    """The rigid transform taking the points ``source`` (N, 3) mm nearest ``target`` (N, 3) mm in
    least squares (Kabsch, by :meth:`Rotation.align_vectors` about the centroids), and the RMS
    distance (mm) left between them."""
    cs, ct = source.mean(axis=0), target.mean(axis=0)
    rot, _ = Rotation.align_vectors(target - ct, source - cs)
    m = rot.as_matrix()
    fit = Rigid(m, ct - m @ cs)
    rms = float(np.sqrt(np.mean(np.sum((fit.apply(source) - target) ** 2, axis=1))))
    return fit, rms


@dataclass(frozen=True)
class Frame:
    """The frame the export writes: ``base`` takes the tracker's coordinates to it, ``platform``
    the tracked body's to its platform frame; ``text`` says which it is, for the files."""

    name: str
    base: Rigid
    platform: Rigid
    text: list[str]


def to_frame(frame: Frame, P: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Poses (P (N, 3) mm, R (N, 3, 3)) of the tracked body in the tracker's frame, as poses of
    the written platform frame in the written base frame (see the module docstring)."""
    Rn = frame.base.rotation @ R @ frame.platform.rotation.T
    Pn = P @ frame.base.rotation.T + frame.base.translation - Rn @ frame.platform.translation
    return Pn, Rn


def from_frame(frame: Frame, P: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of :func:`to_frame`."""
    Rb, Rp = frame.base.rotation, frame.platform.rotation
    Rt = Rb.T @ R @ Rp
    Pt = (P - frame.base.translation + R @ frame.platform.translation) @ Rb
    return Pt, Rt


def drawing_frame(geometry: Robot, drawing: Robot, source: str) -> Frame:
    """The drawing's base and platform frames, each fitted to the calibrated points."""
    base, rms_b = best_fit(geometry.a, drawing.a)
    plat, rms_p = best_fit(geometry.b, drawing.b)
    mm, deg = base.size()
    return Frame(
        "drawing",
        base,
        plat,
        [
            f"frames: LinuxCNC's world frame is the drawing's base frame ({source}): the",
            f"  calibrated base points fitted onto the drawing's (rotation and translation, RMS "
            f"{rms_b:.3f} mm",
            f"  left; the tracker's frame was {mm:.3f} mm and {deg:.3f}° from it); its platform "
            "frame is the",
            f"  drawing's, fitted likewise (RMS {rms_p:.3f} mm); X Y Z is that frame's origin",
        ],
    )


def tracker_frame(unregistered: tuple[float, float] | None) -> Frame:
    """The geometry as fitted; ``unregistered``: (mm, degrees) from the drawing's base frame when
    the drawing is known."""
    text = [
        "frames: LinuxCNC's world frame is the tracker's measurement frame, as the session",
        "  recorded it; its platform frame is the tracked platform's; X Y Z is that frame's origin",
    ]
    if unregistered is not None:
        mm, deg = unregistered
        if mm > UNREGISTERED_MM or deg > UNREGISTERED_DEG:
            text += [
                f"  the drawing's base frame is {mm:.1f} mm and {deg:.2f}° from it: export with",
                "  --base-frame drawing (or a transform) to write the robot's base frame",
            ]
        else:
            text.append(f"  (the drawing's base frame is {mm:.3f} mm and {deg:.3f}° from it)")
    return Frame("tracker", Rigid.identity(), Rigid.identity(), text)


def given_frame(xyzabc: list[float]) -> Frame:
    """The base frame in which the tracker's frame has origin X, Y, Z (mm) and axes A, B, C."""
    base = Rigid(rpy_matrix(np.asarray(xyzabc[3:], float)), np.asarray(xyzabc[:3], float))
    shown = ",".join(f"{v:g}" for v in xyzabc)
    return Frame(
        "given",
        base,
        Rigid.identity(),
        [
            f"frames: LinuxCNC's world frame is the base frame given by --base-frame {shown}",
            "  (the tracker frame's origin X,Y,Z mm and axes A,B,C degrees in it); its platform",
            "  frame is the tracked platform's; X Y Z is that frame's origin",
        ],
    )


@dataclass(frozen=True)
class Recorded:
    """What the calibration session recorded, in the written frame: each leg's readings
    (``readings_min``, ``readings_max`` (6,) mm), the platform's position (``position_min``,
    ``position_max`` (3,) mm) and orientation A, B, C (``abc_min``, ``abc_max`` (3,) degrees)."""

    source: str
    poses: int
    readings_min: np.ndarray
    readings_max: np.ndarray
    position_min: np.ndarray
    position_max: np.ndarray
    abc_min: np.ndarray
    abc_max: np.ndarray

    @classmethod
    def of(cls, meas, frame: Frame, source: str) -> Recorded:
        """The ranges of a measurement table ``meas``, its poses taken into ``frame``."""
        P, R = to_frame(frame, meas.position, meas.rotations.as_matrix())
        abc = rpy_deg(R)
        r = meas.readings
        return cls(
            source,
            len(r),
            r.min(axis=0),
            r.max(axis=0),
            P.min(axis=0),
            P.max(axis=0),
            abc.min(axis=0),
            abc.max(axis=0),
        )

    def outside(self, home_xyzabc: np.ndarray, home_readings: np.ndarray) -> list[str]:
        """One line per coordinate of the home pose (mm, degrees, written frame) and per leg's
        home reading (mm) outside what was recorded; empty when all are inside."""
        out = []
        lo = np.concatenate([self.position_min, self.abc_min])
        hi = np.concatenate([self.position_max, self.abc_max])
        for name, v, a, b in zip("XYZABC", home_xyzabc, lo, hi, strict=True):
            if not a <= v <= b:
                unit = "°" if name in "ABC" else " mm"
                out.append(f"home {name} {v:.2f}{unit}: recorded {a:.2f} … {b:.2f}{unit}")
        for k, (v, a, b) in enumerate(
            zip(home_readings, self.readings_min, self.readings_max, strict=True)
        ):
            if not a <= v <= b:
                out.append(f"leg {k + 1} reads {v:.2f} mm at home: recorded {a:.2f} … {b:.2f} mm")
        return out

    def text(self) -> str:
        lo, hi = self.readings_min.min(), self.readings_max.max()
        return (
            f"{self.source}: {self.poses} poses, readings {lo:.2f} … {hi:.2f} mm, X "
            f"{self.position_min[0]:.1f} … {self.position_max[0]:.1f}, Y "
            f"{self.position_min[1]:.1f} … {self.position_max[1]:.1f}, Z "
            f"{self.position_min[2]:.1f} … {self.position_max[2]:.1f} mm"
        )


class ExportRefused(RefusedError, ValueError):
    """The model cannot be put into LinuxCNC's terms; the message says why and what to do."""


@dataclass(frozen=True)
class Placement:
    """The robot as the export writes it: the ``frame``, the home pose in it (``home`` (6,):
    X, Y, Z mm, A, B, C degrees) and in the tracker's (``home_P`` (3,) mm, ``home_R`` (3, 3)),
    the legs' readings there (``home_readings`` (6,) mm), where the home came from, what the
    session recorded (None when no session was given) and what of the home lies outside it."""

    frame: Frame
    home: np.ndarray
    home_P: np.ndarray
    home_R: np.ndarray
    home_readings: np.ndarray
    home_source: str
    recorded: Recorded | None
    outside: list[str]


def choose_frame(
    choice: str | list[float], geometry: Robot, drawing: Robot | None, name: str
) -> Frame:
    """The :class:`Frame` of ``--base-frame`` (``tracker``, ``drawing`` or six numbers)."""
    if not isinstance(choice, str):
        return given_frame(choice)
    if choice == "drawing":
        if drawing is None:
            raise ExportRefused(
                "--base-frame drawing needs the drawing: pass --drawing robot.json (or --session "
                "with a session file, which carries it)"
            )
        return drawing_frame(geometry, drawing, name)
    size = None if drawing is None else best_fit(geometry.a, drawing.a)[0].size()
    return tracker_frame(size)


def place(
    model: LegModel,
    frame: Frame,
    gain_ppm: np.ndarray | None,
    drawing: tuple[Robot, str] | None,
    session: tuple[object, str] | None,
    home: list[float] | None,
) -> Placement:
    """The home pose in ``frame`` (``home`` (6,) as given by ``--home``, else the drawing's home
    carried into it) and its check against the ``session``'s measurement table; refused when
    the drawing's home lies outside what was recorded (an explicit ``--home`` is written, with
    what lies outside named in the files)."""
    if home is not None:
        xyzabc = np.asarray(home, float)
        source = "--home (X,Y,Z mm, A,B,C degrees, in the frame written)"
    elif drawing is not None:
        robot, name = drawing
        d_frame = drawing_frame(model.robot, robot, name)
        rot = Rotation.from_quat(robot.home.quaternion, scalar_first=True).as_matrix()
        P, R = from_frame(d_frame, np.asarray(robot.home.position, float)[None], rot[None])
        Pw, Rw = to_frame(frame, P, R)
        xyzabc = np.concatenate([Pw[0], rpy_deg(Rw[0])])
        source = f"the drawing's home ({name}), carried into this frame"
    else:
        raise ExportRefused(
            "the home pose: pass --drawing robot.json (its home pose is carried into the frame "
            "written) or --home X,Y,Z,A,B,C (in the frame written)"
        )
    g = np.zeros(6) if gain_ppm is None else gain_ppm * 1e-6
    P, R, readings = _readings_at(model, frame, g, xyzabc)
    recorded = None if session is None else Recorded.of(session[0], frame, session[1])
    outside = [] if recorded is None else recorded.outside(xyzabc, readings)
    if outside and home is None and recorded is not None:
        raise ExportRefused(
            f"the home pose {_pose(xyzabc)} ({source}) lies outside what {recorded.source} "
            "recorded, and a controller homing there would drive the legs past anything "
            "recorded:\n  "
            + "\n  ".join(outside)
            + "\n  pass --home X,Y,Z,A,B,C inside the recorded range"
            + _suggest(model, frame, g, recorded)
        )
    return Placement(frame, xyzabc, P[0], R[0], readings, source, recorded, outside)


def _readings_at(model: LegModel, frame: Frame, g: np.ndarray, xyzabc: np.ndarray):
    """(P (1, 3) mm, R (1, 3, 3): the pose ``xyzabc`` (6,) of the written frame in the tracker's;
    (6,) mm: the legs' readings there as LinuxCNC runs the model, length = offset + (1 + g)·reading
    (the effects it cannot hold left out))."""
    P, R = from_frame(frame, xyzabc[None, :3], rpy_matrix(xyzabc[3:])[None])
    return P, R, (model.geometric(P, R)[0] - model.robot.offsets) / (1 + g)


def _pose(xyzabc: np.ndarray) -> str:
    return (
        "X Y Z "
        + " ".join(f"{v:.2f}" for v in xyzabc[:3])
        + " mm, A B C "
        + " ".join(f"{v:.2f}" for v in xyzabc[3:])
        + "°"
    )


def _suggest(model: LegModel, frame: Frame, g: np.ndarray, recorded: Recorded | None) -> str:
    """A home inside the recorded range to offer: the recorded positions' centre, A B C 0 (or
    the nearest recorded), when every leg's reading there was recorded too."""
    if recorded is None:
        return ""
    pose = np.concatenate(
        [
            (recorded.position_min + recorded.position_max) / 2,
            np.clip(0.0, recorded.abc_min, recorded.abc_max),
        ]
    )
    readings = _readings_at(model, frame, g, pose)[2]
    if recorded.outside(pose, readings):
        return ""
    return (
        f", e.g. --home={','.join(f'{v:.1f}' for v in pose)} (the recorded positions' centre: "
        f"legs read {' '.join(f'{v:.1f}' for v in readings)} mm there)"
    )
