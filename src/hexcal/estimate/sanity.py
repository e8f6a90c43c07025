"""Checks of a calibration against the drawing and of the poses against each other.

A calibration that fits its data can still be wrong in a way no residual shows: with two
encoder cables (or two CSV columns) swapped, the fit simply finds legs 1 and 2 exchanged and a
χ²/dof of 1. The drawing catches it: each fitted point must lie near its own leg's design point
— within a stated tolerance, and nearer its own than any other leg's.

Gross outliers (a typo in one coordinate, a pose taken mid-move, a bumped tracker) are caught
before any fit, at the drawing's geometry: a pose whose leg lengths disagree with its readings
far beyond what the drawing's own errors give the other poses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hexcal.model.robot import Robot

#: A fitted point may lie this fraction of the design radius (base points: the base's, platform
#: points: the platform's) from its design point before the calibration is called off its
#: drawing. A real robot is off its drawing by millimetres, not by a tenth of its size.
DRAWING_TOLERANCE = 0.10
#: A pose is a gross outlier when a leg's length disagrees with its reading this many robust
#: standard deviations (1.4826 MAD over the poses, per leg) beyond the median, at the drawing's
#: geometry...
OUTLIER_ROBUST_SIGMAS = 20.0
#: ...and by at least this much, mm (a drawing good to a few µm does not flag 10 µm).
OUTLIER_MIN_MM = 1.0


@dataclass(frozen=True)
class DrawingFinding:
    """One leg that does not match the drawing, with the likely cause."""

    legs: tuple[int, ...]  #: 1-based
    text: str
    #: "swapped" (two legs exchanged), "other-leg" (nearest another leg), "far" (beyond tolerance)
    kind: str = "far"


def drawing_tolerances(design: Robot, tolerance: float = DRAWING_TOLERANCE) -> tuple[float, float]:
    """(base, platform) tolerance in mm: ``tolerance`` × the mean design radius of each."""
    ra = float(np.linalg.norm(design.a - design.a.mean(axis=0), axis=1).mean())
    rb = float(np.linalg.norm(design.b - design.b.mean(axis=0), axis=1).mean())
    return tolerance * ra, tolerance * rb


def check_against_drawing(
    a: np.ndarray, b: np.ndarray, design: Robot, tolerance: float = DRAWING_TOLERANCE
) -> list[DrawingFinding]:
    """Each fitted leg (a (6, 3), b (6, 3) mm) against the drawing: legs nearer another leg's
    design points (swapped), and legs farther than the tolerance from their own."""
    tol_a, tol_b = drawing_tolerances(design, tolerance)
    # The fit is in the tracker's frame and the tool's: each differs from the drawing's frame by
    # a rigid motion (a tracker not registered to the base, a tool body not on the platform's
    # origin). The points are compared once that motion is taken out.
    a, b = _aligned(a, design.a, tol_a), _aligned(b, design.b, tol_b)
    da = np.linalg.norm(a[:, None, :] - design.a[None], axis=-1)  # (fitted k, design j)
    db = np.linalg.norm(b[:, None, :] - design.b[None], axis=-1)
    d = da / tol_a + db / tol_b
    nearest = np.argmin(d, axis=1)
    findings: list[DrawingFinding] = []
    done: set[int] = set()
    for k in range(6):
        j = int(nearest[k])
        if j == k or k in done:
            continue
        if nearest[j] == k:
            done |= {k, j}
            findings.append(
                DrawingFinding(
                    (k + 1, j + 1),
                    f"legs {k + 1} and {j + 1} look swapped: the points fitted for leg {k + 1} "
                    f"lie at leg {j + 1}'s on the drawing and the other way round — swapped "
                    f"encoder cables, swapped columns (rho{k + 1} ↔ rho{j + 1}) or node ids of "
                    "the two encoders",
                    "swapped",
                )
            )
        else:
            done.add(k)
            findings.append(
                DrawingFinding(
                    (k + 1,),
                    f"leg {k + 1}'s fitted points lie nearest leg {j + 1}'s on the drawing: its "
                    "readings come from another leg's encoder (a wrong node id or column), or "
                    "the legs are numbered otherwise than on the drawing",
                    "other-leg",
                )
            )
    for k in range(6):
        if k in done:
            continue
        off_a, off_b = float(da[k, k]), float(db[k, k])
        if off_a > tol_a or off_b > tol_b:
            findings.append(
                DrawingFinding(
                    (k + 1,),
                    f"leg {k + 1}'s fitted points lie {off_a:.1f} mm (base) and {off_b:.1f} mm "
                    f"(platform) from the drawing (tolerance {tol_a:.1f} and {tol_b:.1f} mm): a "
                    "wrong sign or scale of its reading, a wrong leg offset in robot.json, or "
                    "a wrong drawing",
                )
            )
    return findings


def _aligned(points: np.ndarray, design: np.ndarray, tol: float) -> np.ndarray:
    """``points`` (6, 3) moved by the rigid motion that best lays them on ``design`` (6, 3),
    leg for leg (the Kabsch solution), found on the legs that agree: the worst leg beyond
    ``tol`` mm is left out of the alignment and it is solved again, keeping at least four, so
    one wrong leg does not drag the others off."""
    from scipy.spatial.transform import Rotation

    keep = np.ones(len(points), bool)
    while True:
        pc, dc = points[keep].mean(axis=0), design[keep].mean(axis=0)
        rot, _ = Rotation.align_vectors(design[keep] - dc, points[keep] - pc)
        moved = rot.apply(points - pc) + dc
        off = np.where(keep, np.linalg.norm(moved - design, axis=1), -1.0)
        worst = int(np.argmax(off))
        if off[worst] <= tol or keep.sum() <= 4:
            return moved
        keep[worst] = False


#: A fitted geometry whose base or platform is this many times the drawing's size, or whose
#: offsets lie this many leg lengths from the drawing's, has left every plausible value: the
#: fit diverged (a real robot is off its drawing by millimetres).
DIVERGED_FACTOR = 10.0


def divergence(a: np.ndarray, b: np.ndarray, offsets: np.ndarray, design: Robot) -> str | None:
    """How a fitted geometry (a (6, 3), b (6, 3), offsets (6,) mm) left every plausible value,
    in words, or None when it did not. Only sizes are compared (the fit is in the tracker's
    frame, which may lie anywhere)."""
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b)) and np.all(np.isfinite(offsets))):
        return "the fitted geometry is not finite"

    def radius(p: np.ndarray) -> float:
        return float(np.linalg.norm(p - p.mean(axis=0), axis=1).max())

    for name, fit, ref in (("base", a, design.a), ("platform", b, design.b)):
        if radius(fit) > DIVERGED_FACTOR * max(radius(ref), 1.0):
            return (
                f"the fitted {name} spans {radius(fit):.3g} mm across, against {radius(ref):.3g} "
                "mm on the drawing"
            )
    lengths = np.linalg.norm(design.a - design.b, axis=1)
    span = DIVERGED_FACTOR * max(
        float(np.mean(lengths)), float(np.max(np.abs(design.offsets))), 1.0
    )
    worst = int(np.argmax(np.abs(offsets - design.offsets)))
    if abs(offsets[worst] - design.offsets[worst]) > span:
        return (
            f"leg {worst + 1}'s fitted offset is {offsets[worst]:.3g} mm, against "
            f"{design.offsets[worst]:.3g} mm on the drawing"
        )
    return None


@dataclass(frozen=True)
class OutlierPose:
    """A pose whose leg lengths disagree with its readings far beyond the others'."""

    index: int  #: 0-based row
    pose_id: int
    step: str
    t: float
    leg: int  #: 1-based, the worst leg
    deviation_mm: float
    robust_sigmas: float

    def text(self) -> str:
        return (
            f"pose {self.pose_id} (step {self.step}, t {self.t:g} s): leg {self.leg}'s length "
            f"disagrees with its reading by {self.deviation_mm:.3g} mm beyond the other poses "
            f"({self.robust_sigmas:.0f} robust σ)"
        )


def gross_outliers(meas, design: Robot) -> list[OutlierPose]:
    """Poses whose residual at the drawing's geometry (length − reading − offset, per leg) lies
    beyond :data:`OUTLIER_ROBUST_SIGMAS` robust standard deviations and :data:`OUTLIER_MIN_MM`
    from the leg's median over the session. The drawing's own errors vary smoothly over the
    workspace and stay within this spread; a typo or a pose taken mid-move does not."""
    rot = meas.rotations.as_matrix()
    v = meas.position[:, None, :] + np.einsum("mij,kj->mki", rot, design.b) - design.a[None]
    r = np.linalg.norm(v, axis=-1) - meas.readings - design.offsets
    dev = np.abs(r - np.median(r, axis=0))
    scale = 1.4826 * np.median(dev, axis=0)
    score = dev / np.maximum(scale, 1e-9)
    bad = (score > OUTLIER_ROBUST_SIGMAS) & (dev > OUTLIER_MIN_MM)
    out = []
    for i in np.where(bad.any(axis=1))[0]:
        k = int(np.argmax(np.where(bad[i], dev[i], -1.0)))
        out.append(
            OutlierPose(
                int(i),
                int(meas.pose_id[i]),
                str(meas.step[i]),
                float(meas.t[i]),
                k + 1,
                float(dev[i, k]),
                float(score[i, k]),
            )
        )
    return out


def outlier_message(outliers: list[OutlierPose], source: str) -> str:
    """The refusal naming the outlier poses and what to do."""
    shown = "\n".join(f"  {o.text()}" for o in outliers[:10])
    more = f"\n  … and {len(outliers) - 10} more" if len(outliers) > 10 else ""
    ids = " ".join(str(o.pose_id) for o in outliers)
    return (
        f"{source}: {len(outliers)} pose(s) are gross outliers — a typo, a pose taken mid-move or "
        f"a bumped tracker:\n{shown}{more}\n"
        f"fix them in the table, or leave them out with --exclude-poses {ids}"
    )
