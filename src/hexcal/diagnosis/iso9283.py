"""ISO 9283 pose accuracy and pose repeatability of a model at the standard's five test poses.

The poses of a session's ``iso9283`` step (:mod:`hexcal.model.iso_tests`: P1…P5 in the test
cube, 30 cycles) are assigned to the test pose they are nearest (within half the distance
between two test poses; others are counted and left out). For each test pose, over its n
visits j (ISO 9283:1998, pose accuracy and repeatability, 7.2):

- the **attained** pose is the tracker's: position x_j (mm) and orientation angles a_j, b_j,
  c_j (degrees, rotations about the measurement frame's x, y, z axes: R = R_z(c) R_y(b) R_x(a),
  the roll-pitch-yaw of LinuxCNC's A, B, C);
- the **commanded** pose is the one the model computes from the readings the encoders reached:
  what a controller running this model reports having commanded (hexcal does not know what a
  controller was sent; a servo error therefore shows in the repeatability, not the accuracy);
- **AP_P** = |x̄ − x̄_c| (mm), the distance between the barycentre of the attained positions and
  the mean commanded one; **AP_a, AP_b, AP_c** = ā − ā_c etc. (degrees);
- **RP_l** = l̄ + 3 S_l (mm), l_j = |x_j − x̄|, S_l = √(Σ (l_j − l̄)² / (n − 1));
  **RP_a, RP_b, RP_c** = ± 3 S_a etc. (degrees).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.effects.covariates import numeric_columns
from hexcal.estimate.predict import LegModel, Poses
from hexcal.model.iso_tests import Cube, iso9283_cube

#: The step name of the test's poses in a session.
STEP = "iso9283"


@dataclass(frozen=True)
class PoseFigures:
    """The figures at one test pose (module docstring): mm and degrees."""

    label: str
    visits: int
    commanded_mm: np.ndarray  #: (3,) x̄_c
    ap_p_mm: float
    ap_deg: np.ndarray  #: (3,) AP_a, AP_b, AP_c
    rp_l_mm: float
    rp_deg: np.ndarray  #: (3,) RP_a, RP_b, RP_c (the ± half-width)

    def to_dict(self) -> dict:
        return {
            "pose": self.label,
            "cycles": self.visits,
            "commanded_mm": self.commanded_mm.tolist(),
            "AP_P_mm": self.ap_p_mm,
            "AP_a_deg": float(self.ap_deg[0]),
            "AP_b_deg": float(self.ap_deg[1]),
            "AP_c_deg": float(self.ap_deg[2]),
            "RP_l_mm": self.rp_l_mm,
            "RP_a_deg": float(self.rp_deg[0]),
            "RP_b_deg": float(self.rp_deg[1]),
            "RP_c_deg": float(self.rp_deg[2]),
        }


@dataclass(frozen=True)
class Iso9283:
    """ISO 9283 figures of one model on one session's ``iso9283`` poses."""

    cube: Cube
    poses: list[PoseFigures]
    left_out: int  #: the step's poses near no test pose

    def to_dict(self) -> dict:
        return {
            "cube_edge_mm": self.cube.edge,
            "cube_centre_mm": self.cube.centre.tolist(),
            "cube": self.cube.text(),
            "poses": [p.to_dict() for p in self.poses],
            "left_out": self.left_out,
        }

    def lines(self) -> list[str]:
        out = [
            f"ISO 9283 ({self.cube.text()}):",
            "  pose  cycles   AP_P mm   AP_a °    AP_b °    AP_c °    RP_l mm   RP_a ±°  "
            " RP_b ±°   RP_c ±°",
        ]
        for p in self.poses:
            out.append(
                f"  {p.label:<4} {p.visits:7d}  {p.ap_p_mm:8.4f}  "
                + "".join(f"{v:+9.5f} " for v in p.ap_deg)
                + f"{p.rp_l_mm:8.4f}  "
                + "".join(f"{v:8.5f}  " for v in p.rp_deg).rstrip()
            )
        if self.left_out:
            out.append(f"  {self.left_out} poses of the step are near no test pose: left out")
        return out


def rpy_deg(rotation: np.ndarray) -> np.ndarray:
    """(N, 3) degrees: roll a, pitch b, yaw c about the fixed x, y, z axes."""
    return Rotation.from_matrix(rotation).as_euler("xyz", degrees=True)


def figures_at_pose(label: str, attained: Poses, commanded: Poses) -> PoseFigures:
    """The figures of one test pose from its n visits: ``attained`` (the tracker's) and
    ``commanded`` (the model's) poses, n each."""
    x = attained.position
    xbar = x.mean(axis=0)
    xc = commanded.position.mean(axis=0)
    ang = rpy_deg(attained.rotation)
    ang_c = rpy_deg(commanded.rotation)
    n = len(x)
    l_j = np.linalg.norm(x - xbar, axis=1)
    s_l = float(np.std(l_j, ddof=1)) if n > 1 else float("nan")
    s_ang = np.std(ang, axis=0, ddof=1) if n > 1 else np.full(3, np.nan)
    return PoseFigures(
        label,
        n,
        xc,
        float(np.linalg.norm(xbar - xc)),
        ang.mean(axis=0) - ang_c.mean(axis=0),
        float(l_j.mean() + 3.0 * s_l),
        3.0 * s_ang,
    )


def iso9283(model: LegModel, meas) -> Iso9283 | None:
    """The figures of ``model`` on the ``iso9283`` poses of the table ``meas`` (None without
    any)."""
    rows = np.where(meas.step == STEP)[0]
    if not len(rows):
        return None
    cube = iso9283_cube(model.robot)
    labels, targets, _ = cube.poses()
    pos = meas.position[rows]
    dist = np.linalg.norm(pos[:, None, :] - targets[None], axis=-1)
    spacing = np.min(np.linalg.norm(targets[:, None] - targets[None], axis=-1) + 1e9 * np.eye(5))
    nearest = np.argmin(dist, axis=1)
    near = dist[np.arange(len(rows)), nearest] < 0.5 * spacing
    sub = meas.subset(rows)
    rot = sub.rotations.as_matrix()
    model = model.with_columns(numeric_columns(sub.extra))
    solved, closed = model.solve_poses(sub.readings, sub.t, sub.temperature, Poses(pos, rot))
    poses = []
    for i, label in enumerate(labels):
        take = near & closed & (nearest == i)
        if take.sum() < 2:
            continue
        attained = Poses(pos[take], rot[take])
        commanded = Poses(solved.position[take], solved.rotation[take])
        poses.append(figures_at_pose(label, attained, commanded))
    return Iso9283(cube, poses, int((~(near & closed)).sum()))
