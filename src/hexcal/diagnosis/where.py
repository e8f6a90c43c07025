"""Where the residual concentrates: legs, procedure steps, time, workspace, worst poses.

Each group's mean squared normalised residual ``(r / floor)²`` is compared with 1, the value
noise alone gives. The six legs of a pose share its tracker noise, so a group of n residuals
from n_p poses carries about n_p independent χ²₁ terms, not n; a group stands out when its mean
exceeds 1 by more than 5 standard errors of a χ² mean over n_p terms (about forty groups are
tested) and is at least twice the noise — and when it also stands out from the rest of the
session: it exceeds the session's own noise level (``level``, the s² the outlier search uses,
from the median pose) by 5 standard errors at that level. A residual raised alike everywhere
(the stated noise too low) then points at no group: it is *spread evenly*, and the summary
says so instead of naming the groups that noise happened to raise most. The summary tells one
story with the outlier search and the change-point search: the poses set aside and the legs
whose zero changed come first, then where the rest of the residual lies.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

#: Median of χ²(1): a squared normalised residual's median when it is noise alone.
MEDIAN_CHI2_1 = 0.454936423119572
#: Groups of the summary (``leg_region`` is tested on its own z).
GROUPS = ("legs", "steps", "time", "region", "leg_region")


def robust_level(z2: np.ndarray) -> float:
    """The noise level of the squared normalised residuals ``z2`` from their median (robust to
    a leg, a stretch of time or a region far out), never below 1 (the floor): what a residual
    raised alike everywhere sits at, and what a group must stand out from."""
    return max(1.0, float(np.median(z2)) / MEDIAN_CHI2_1)


def _group(z2: np.ndarray, mask: np.ndarray, label: str, level: float = 1.0) -> dict | None:
    n = int(mask.sum())
    if n < 6:
        return None
    poses = int(mask.reshape(len(mask), -1).any(axis=1).sum())
    ratio = float(z2[mask].mean())
    se = np.sqrt(2 / poses)
    threshold = max(2.0, 1 + 5 * se, level * (1 + 5 * se))
    return {"group": label, "n": n, "excess_ratio": ratio, "stands_out": bool(ratio > threshold)}


def concentrations(
    problem,
    fit,
    floor: np.ndarray,
    *,
    excess: bool = False,
    outliers: Sequence = (),
    changes: Sequence = (),
) -> dict:
    """A dict: ``legs``, ``steps``, ``time``, ``region`` (lists of groups with their excess
    ratio), ``worst_poses``, ``worst_legs``, ``overall`` (the mean ratio), ``even`` (no group
    stands out), ``level`` (the session's own noise level a group must also stand out from:
    :func:`robust_level`) and a one-line ``summary``. ``excess``: the residual exceeds the
    floor (then a residual that stands out nowhere is "spread evenly", not "at the floor");
    ``outliers`` and ``changes``: the poses set aside and the located zero steps, named first
    in the summary."""
    meas = problem.meas
    r = fit.residuals
    z2 = (r / floor) ** 2
    m = len(r)
    level = robust_level(z2)
    legs = [g for k in range(6) if (g := _group(z2[:, k], np.ones(m, bool), f"leg {k + 1}", level))]
    steps = []
    for step in dict.fromkeys(meas.step.tolist()):
        g = _group(z2, np.repeat((meas.step == step)[:, None], 6, 1), f"step {step}", level)
        if g:
            steps.append(g)
    pos = meas.position - np.median(meas.position, axis=0)
    worst_legs = [
        g["group"] for g in sorted(legs, key=lambda g: -g["excess_ratio"]) if g["stands_out"]
    ]
    out: dict[str, Any] = {
        "legs": legs,
        "steps": steps,
        "time": _time_blocks(z2, meas, level),
        "region": _regions(z2, pos, meas.rotations.magnitude(), level),
        "leg_region": _leg_regions(r, floor, pos),
        "worst_poses": _worst_poses(z2, meas),
        "worst_legs": worst_legs,
        "overall": float(z2.mean()),
        "level": float(level),
    }
    out["even"] = not any(g["stands_out"] for key in GROUPS for g in out[key])
    out["summary"] = _summary(out, excess, outliers, changes)
    return out


def _time_blocks(z2: np.ndarray, meas, level: float = 1.0) -> list[dict]:
    """The groups of five consecutive blocks of poses, in recording order."""
    m = len(z2)
    time = []
    for i, block in enumerate(np.array_split(np.arange(m), 5)):
        mask = np.zeros((m, 6), bool)
        mask[block] = True
        g = _group(
            z2,
            mask,
            f"time block {i + 1}/5 (poses {meas.pose_id[block[0]]}–{meas.pose_id[block[-1]]})",
            level,
        )
        if g:
            time.append(g)
    return time


def _regions(z2: np.ndarray, pos: np.ndarray, tilt: np.ndarray, level: float = 1.0) -> list[dict]:
    """The groups of the workspace's halves: platform position ``pos`` (about its median) along
    each axis, and ``tilt`` (rotation magnitude) above and below its median."""
    region = []
    for label, sel in [
        ("platform x > median", pos[:, 0] > 0),
        ("platform x < median", pos[:, 0] <= 0),
        ("platform y > median", pos[:, 1] > 0),
        ("platform y < median", pos[:, 1] <= 0),
        ("platform z > median", pos[:, 2] > 0),
        ("platform z < median", pos[:, 2] <= 0),
        ("tilt > median", tilt > np.median(tilt)),
        ("tilt < median", tilt <= np.median(tilt)),
    ]:
        g = _group(z2, np.repeat(sel[:, None], 6, 1), label, level)
        if g:
            region.append(g)
    return region


def _leg_regions(r: np.ndarray, floor: np.ndarray, pos: np.ndarray) -> list[dict]:
    """Within each leg, a local defect shows as a difference between the two halves of the
    workspace: the fit spreads a step over both halves, so each half alone only looks like the
    leg's overall excess, but their signed means differ. z = difference / its standard error
    (pose noise, so one term per pose)."""
    leg_region = []
    for k in range(6):
        for axis, name in enumerate("xyz"):
            hi = pos[:, axis] > 0
            if hi.sum() < 6 or (~hi).sum() < 6:
                continue
            zk = r[:, k] / floor[:, k]
            diff = zk[hi].mean() - zk[~hi].mean()
            se = np.sqrt(zk[hi].var(ddof=1) / hi.sum() + zk[~hi].var(ddof=1) / (~hi).sum())
            z = float(diff / se)
            um = 1000 * float(r[hi, k].mean() - r[~hi, k].mean())
            leg_region.append(
                {
                    "group": f"leg {k + 1}, between platform {name} above and below its median "
                    f"(residual differs by {abs(um):.0f} µm)",
                    "n": len(zk),
                    "z": z,
                    "difference_um": um,
                    "excess_ratio": float(np.mean(zk**2)),
                    "stands_out": bool(abs(z) > 6.0),
                }
            )
    return leg_region


def _worst_poses(z2: np.ndarray, meas) -> list[dict]:
    """The five poses with the largest mean squared normalised residual."""
    pose_score = z2.mean(axis=1)
    worst = np.argsort(-pose_score)[:5]
    return [
        {
            "pose_id": int(meas.pose_id[i]),
            "step": str(meas.step[i]),
            "excess_ratio": float(pose_score[i]),
            "worst_leg": int(np.argmax(z2[i])) + 1,
        }
        for i in worst
    ]


def _summary(out: dict, excess: bool, outliers: Sequence, changes: Sequence) -> str:
    """One line: the poses set aside and the zero steps, then the groups of ``out`` that stand
    out (the largest excess first) — or that the rest is spread evenly, or at the floor."""
    standouts = [g for key in GROUPS for g in out[key] if g["stands_out"]]
    standouts.sort(key=lambda g: -g["excess_ratio"])
    first = []
    if outliers:
        ids = " ".join(f"#{o.pose_id}" for o in outliers[:10])
        more = " …" if len(outliers) > 10 else ""
        first.append(
            f"{len(outliers)} pose{'s' * (len(outliers) > 1)} set aside as outliers ({ids}{more})"
        )
    first += [
        f"leg {c.leg} reads {abs(1000 * c.size_mm):.0f} µm {'long' if c.size_mm > 0 else 'short'} "
        f"from pose {c.pose_id} on"
        for c in changes
    ]
    if standouts:
        body = "concentrated in " + "; ".join(
            f"{g['group']} (z = {abs(g['z']):.0f})"
            if "z" in g
            else f"{g['group']} ({g['excess_ratio']:.1f}× noise)"
            for g in standouts[:4]
        )
    elif excess:
        body = (
            f"spread evenly over the legs, steps, time and workspace at {out['overall']:.1f}× "
            "the noise floor (no group stands out from the rest)"
        )
    else:
        body = "residual at the noise floor everywhere"
    return "; ".join([*first, ("the rest: " if first else "") + body])
