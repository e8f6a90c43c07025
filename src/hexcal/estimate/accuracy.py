"""Pose accuracy: the number a lab reports.

For each pose, the model computes the platform pose from the six readings (forward kinematics
with its effects, :mod:`hexcal.estimate.predict`) and compares it with the pose the tracker measured:
position error at the platform origin (mm) and orientation error (the angle of the rotation
between them, degrees). Reported as RMS, 95th percentile and maximum, for poses the fit did not
see (each from the cross-validation fold that held it out), beside the floor the instruments'
noise alone gives:

    Cov(pose error) = σ_ρ² J⁻¹ J⁻ᵀ + diag(σ_p² I₃, σ_θ² I₃)

with J the leg-rate Jacobian at the pose (the readings' noise through the kinematics) plus the
tracker's own noise; the floor is √(mean trace) of the position and orientation blocks.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from hexcal.effects.covariates import numeric_columns
from hexcal.estimate.predict import LegModel, Poses
from hexcal.model.batched import inverse_and_precision
from hexcal.model.noise import NoiseSigmas

#: Poses per block of :func:`pose_floor`'s whole-array computations.
FLOOR_BLOCK = 8192


def floor_cap(floor_rms_mm: float, heldout_rms_mm: Iterable[float]) -> float:
    """The factor (≤ 1) by which a floor estimated from a fit's residual (no instruments file)
    comes down to the held-out leg-length RMS of the best model tried, ``heldout_rms_mm`` (mm):
    noise alone can leave no more than the best model leaves on poses it did not see, so an
    estimate above that (a guessed mix of tracker and encoder noise turned into mm) is not
    what the data support. 1 when the estimate is already at or below it."""
    finite = [h for h in heldout_rms_mm if np.isfinite(h) and h > 0]
    if not finite or not floor_rms_mm > 0:
        return 1.0
    return float(min(1.0, min(finite) / floor_rms_mm))


def floor_words(estimated: bool) -> str:
    """What a floor is called: "estimated floor" when no instrument's noise was stated (it was
    estimated from the residual), else "floor"."""
    return "estimated floor" if estimated else "floor"


@dataclass(frozen=True)
class PoseErrors:
    """Per pose: ``position_mm`` (N,) and ``orientation_deg`` (N,) errors of the model's pose
    against the tracker's; ``closed`` (N,) False where no pose gives the readings' lengths."""

    position_mm: np.ndarray
    orientation_deg: np.ndarray
    closed: np.ndarray

    def take(self, rows: np.ndarray) -> PoseErrors:
        return PoseErrors(self.position_mm[rows], self.orientation_deg[rows], self.closed[rows])


def pose_errors(model: LegModel, meas, rows: np.ndarray | None = None) -> PoseErrors:
    """The model's pose from each row's readings against the tracker's pose (every row of the
    measurement table ``meas``, or the rows ``rows``; the effects see the whole table in
    recording order: backlash needs the history)."""
    rot = meas.rotations.as_matrix()
    guess = Poses(meas.position, rot)
    model = model.with_columns(numeric_columns(meas.extra))  # a lab's sensors, if it reads them
    poses, closed = model.solve_poses(meas.readings, meas.t, meas.temperature, guess, rows)
    if rows is not None:
        rot = rot[rows]
    dp = np.linalg.norm(
        poses.position - (meas.position if rows is None else meas.position[rows]), axis=1
    )
    rel = np.einsum("nji,njk->nik", rot, poses.rotation)  # Rᵀ_tracker R_model
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return PoseErrors(dp, np.degrees(np.arccos(cos)), closed)


def pose_floor(a: np.ndarray, b: np.ndarray, meas, sig: NoiseSigmas) -> tuple[float, float]:
    """(position mm, orientation deg): the RMS pose error the noise alone gives at the table's
    poses, for geometry a, b (6, 3) mm (see module docstring).

    ``J⁻¹J⁻ᵀ = (JᵀJ)⁻¹``: its diagonal blocks' traces come from the normal matrix's inverse,
    computed over all poses at once (:mod:`hexcal.model.batched`), in blocks."""
    R = meas.rotations.as_matrix()
    pos = ang = 0.0
    for start in range(0, len(R), FLOOR_BLOCK):
        blk = slice(start, start + FLOOR_BLOCK)
        p, r = meas.position[blk].T, R[blk].transpose(1, 2, 0)
        rb = [b @ r[i] for i in range(3)]  # (R b_k)_i, (6, n)
        v = [rb[i] + (p[i] - a[:, i, None]) for i in range(3)]
        norm = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        n = [c / norm for c in v]
        cols = [
            *n,
            rb[1] * n[2] - rb[2] * n[1],
            rb[2] * n[0] - rb[0] * n[2],
            rb[0] * n[1] - rb[1] * n[0],
        ]
        jtj = np.empty((6, 6, len(norm[0])))
        for i in range(6):
            for j in range(i + 1):
                jtj[i, j] = jtj[j, i] = np.sum(cols[i] * cols[j], axis=0)
        inv = inverse_and_precision(jtj)[1]  # (JᵀJ)⁻¹, (6, 6, n)
        pos += float(np.sum(inv[0, 0] + inv[1, 1] + inv[2, 2]))
        ang += float(np.sum(inv[3, 3] + inv[4, 4] + inv[5, 5]))
    m = len(R)
    pos = sig.reading_mm**2 * pos / m + 3 * sig.position_mm**2
    ang = sig.reading_mm**2 * ang / m + 3 * sig.orientation_rad**2
    return float(np.sqrt(pos)), float(np.degrees(np.sqrt(ang)))


@dataclass(frozen=True)
class PoseAccuracy:
    """Pose accuracy of one model on a set of poses (see module docstring)."""

    model: str
    heldout: bool
    poses: int
    position_rms_mm: float
    position_p95_mm: float
    position_max_mm: float
    orientation_rms_deg: float
    orientation_p95_deg: float
    orientation_max_deg: float
    failed: int = 0
    leg_rms_mm: float | None = None
    floor_position_rms_mm: float | None = None
    floor_orientation_rms_deg: float | None = None
    #: The floor comes from noise estimated from a residual, not from stated instruments
    floor_estimated: bool = False

    @classmethod
    def of(
        cls,
        model: str,
        errors: PoseErrors,
        heldout: bool,
        leg_rms_mm: float | None = None,
        floor: tuple[float, float] | None = None,
    ) -> PoseAccuracy:
        ok = errors.closed
        p, o = errors.position_mm[ok], errors.orientation_deg[ok]
        if not len(p):
            p = o = np.array([np.nan])

        def rms(x: np.ndarray) -> float:
            return float(np.sqrt(np.mean(x**2)))

        return cls(
            model,
            heldout,
            int(ok.sum()),
            rms(p),
            float(np.percentile(p, 95)),
            float(p.max()),
            rms(o),
            float(np.percentile(o, 95)),
            float(o.max()),
            int((~ok).sum()),
            leg_rms_mm,
            None if floor is None else floor[0],
            None if floor is None else floor[1],
        )

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}

    def line(self) -> str:
        """One line: position and orientation error, RMS (p95, max)."""
        s = (
            f"position {_mm(self.position_rms_mm)} RMS (95 % {_mm(self.position_p95_mm)}, max "
            f"{_mm(self.position_max_mm)}), orientation {self.orientation_rms_deg:.4f}° RMS "
            f"(95 % {self.orientation_p95_deg:.4f}°, max {self.orientation_max_deg:.4f}°)"
        )
        if self.failed:
            s += f"; {self.failed} poses out of the workspace"
        return s


def _mm(v: float) -> str:
    return f"{v:.4f} mm" if v < 1 else f"{v:.3f} mm"


def accuracy_table(rows: list[PoseAccuracy]) -> str:
    """The error falling, model by model: leg-length RMS and pose error side by side."""
    out = [
        "  model                             leg RMS mm   position RMS mm  p95 mm     "
        "orientation RMS deg",
    ]
    for r in rows:
        leg = f"{r.leg_rms_mm:10.4f}" if r.leg_rms_mm is not None else f"{'—':>10}"
        out.append(
            f"  {r.model:<33} {leg}   {r.position_rms_mm:15.4f}  {r.position_p95_mm:9.4f}  "
            f"{r.orientation_rms_deg:10.5f}"
        )
    last = rows[-1] if rows else None
    if last is not None and last.floor_position_rms_mm is not None:
        out.append(
            f"  {'noise floor':<33} {'':>10}   {last.floor_position_rms_mm:15.4f}  {'':>9}  "
            f"{last.floor_orientation_rms_deg:10.5f}"
        )
    kind = "held-out poses (5 random folds)" if any(r.heldout for r in rows) else "these poses"
    out.append(
        f"  (pose error: the pose the model computes from the readings against the tracker's, on {kind})"
    )
    return "\n".join(out)
