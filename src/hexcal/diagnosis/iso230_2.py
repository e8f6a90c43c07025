"""ISO 230-2 positioning figures of each leg: accuracy A, repeatability R, reversal value B.

Each leg is one axis of the machine. For leg k at the poses of a session, in recording order:

- an **approach** is a pose at which the leg's reading changed since the previous pose by more
  than the backlash dead band (:func:`hexcal.effects.backlash.deadband_mm`); its **direction**
  (↑ or ↓) is the sign of that change. A pose at which the leg did not move is no approach (the
  leg held still while others moved);
- a **target** P_i is a set of approaches whose readings lie within :data:`TARGET_TOLERANCE_MM`
  of the lowest of them (a servo settles an encoder within µm of its target; a robot moved by
  its pose lands within its play of it); the figures use the targets approached at least :data:`MIN_APPROACHES` times
  from each side (ISO 230-2 asks for five);
- the **deviation** x_ij (mm) of approach j is the leg's actual length less its indicated one:
  the length the tracker's pose gives through the calibrated geometry, ``|P + R b_k − a_k|``,
  less the length the model gives for the reading **without its backlash term** (reading +
  offset + the other effects): backlash is what B measures, so it is never subtracted first.

Then, with ISO 230-2's definitions (targets i, directions ↑ ↓, n approaches each): the mean unidirectional
deviations x̄_i↑, x̄_i↓, their standard uncertainties s_i↑, s_i↓ (n − 1 in the denominator),
the reversal value B_i = x̄_i↑ − x̄_i↓; unidirectional repeatability R_i↑ = 4 s_i↑;
bidirectional repeatability R_i = max(2 s_i↑ + 2 s_i↓ + |B_i|, R_i↑, R_i↓);

- **B** = max |B_i|, and the mean reversal value **B̄** = mean B_i (with its standard error
  σ_B̄ from the s_i: the play the drive has is −B̄ in hexcal's backlash convention);
- **R** = max R_i;
- **A** = max_i (x̄_i + 2 s_i) − min_i (x̄_i − 2 s_i), both directions; A↑ and A↓ for one;
- **E**, the systematic positioning error, = max − min of the mean deviations x̄_i↑, x̄_i↓ of
  both directions; E↑ and E↓ for one;
- **M**, the mean bidirectional positioning error, = max − min of x̄_i = (x̄_i↑ + x̄_i↓)/2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hexcal.effects.backlash import deadband_mm
from hexcal.estimate.predict import LegModel

#: Readings of one leg within this of the lowest are one target, mm: far above a servo's or an
#: encoder's scatter and a typical play, far below a test's target spacing; poses an operator
#: chose freely rarely meet it, so a session without a test contributes few targets.
TARGET_TOLERANCE_MM = 0.1
#: Approaches from each side a target needs to count (ISO 230-2 asks for five).
MIN_APPROACHES = 2


@dataclass(frozen=True)
class LegPositioning:
    """ISO 230-2 figures of one leg (1..6), mm."""

    leg: int
    targets: int
    approaches: int  #: over all targets and both directions
    accuracy_mm: float  #: A
    accuracy_up_mm: float  #: A↑
    accuracy_down_mm: float  #: A↓
    repeatability_mm: float  #: R
    reversal_mm: float  #: B = max |B_i|
    mean_reversal_mm: float  #: B̄, signed
    mean_reversal_sigma_mm: float  #: σ of B̄
    systematic_mm: float  #: E
    systematic_up_mm: float  #: E↑
    systematic_down_mm: float  #: E↓
    mean_bidirectional_mm: float  #: M

    def to_dict(self) -> dict:
        return {
            "leg": self.leg,
            "targets": self.targets,
            "approaches": self.approaches,
            "A_mm": self.accuracy_mm,
            "A_up_mm": self.accuracy_up_mm,
            "A_down_mm": self.accuracy_down_mm,
            "R_mm": self.repeatability_mm,
            "B_mm": self.reversal_mm,
            "B_mean_mm": self.mean_reversal_mm,
            "B_mean_sigma_mm": self.mean_reversal_sigma_mm,
            "E_mm": self.systematic_mm,
            "E_up_mm": self.systematic_up_mm,
            "E_down_mm": self.systematic_down_mm,
            "M_mm": self.mean_bidirectional_mm,
        }


def table_lines(legs: list[LegPositioning]) -> list[str]:
    """The figures as a text table, one leg a row (µm)."""
    out = [
        "ISO 230-2 per leg (µm; deviation = tracker length − model length without backlash):",
        # 74 columns: with the report's indent, the text UI's 76 at 80×24. Each header ends
        # over its numbers' last digit (B̄ is two characters, one column).
        f"  leg targets approaches {'A':>6} {'R':>6} {'B':>6} {'':>9}B̄ ± σ {'E':>6} {'M':>6}",
    ]
    for p in legs:
        out.append(
            f"  {p.leg:3d} {p.targets:7d} {p.approaches:10d} {1000 * p.accuracy_mm:6.1f} "
            f"{1000 * p.repeatability_mm:6.1f} {1000 * p.reversal_mm:6.1f} "
            f"{1000 * p.mean_reversal_mm:+6.1f} ± {1000 * p.mean_reversal_sigma_mm:5.1f} "
            f"{1000 * p.systematic_mm:6.1f} {1000 * p.mean_bidirectional_mm:6.1f}"
        )
    return out


def without_backlash(model: LegModel) -> LegModel:
    """``model`` less its backlash term (B is what the figures measure)."""
    if "backlash" not in model.effects:
        return model
    keep: list[str] = []
    values: list[float] = []
    i = 0
    from hexcal.effects import get_effect

    for e in model.effects:
        n = len(get_effect(e).params(model.robot))
        if e != "backlash":
            keep.append(e)
            values.extend(model.values[i : i + n])
        i += n
    return LegModel(model.robot, tuple(keep), np.array(values))


def deviations(model: LegModel, meas) -> np.ndarray:
    """(M, 6) mm: each leg's length from the tracker's pose less the model's from its reading,
    backlash left out (module docstring)."""
    plain = without_backlash(model)
    rot = meas.rotations.as_matrix()
    lengths = plain.lengths(meas.readings, meas.position, rot, meas.t, meas.temperature)
    return plain.geometric(meas.position, rot) - lengths


def _targets(readings: np.ndarray) -> np.ndarray:
    """Target index (n,) of each approach: from the lowest reading up, each target takes the
    readings within the tolerance of its lowest."""
    order = np.argsort(readings)
    labels = np.empty(len(readings), int)
    label, start = -1, -np.inf
    for i in order:
        if readings[i] > start + TARGET_TOLERANCE_MM:
            label, start = label + 1, readings[i]
        labels[i] = label
    return labels


def leg_figures(leg: int, readings: np.ndarray, dev: np.ndarray, deadband: float):
    """The figures of one leg from its readings (M,) and deviations (M,) mm in recording order;
    None when no target was approached from both sides often enough."""
    step = np.diff(readings)
    moved = np.concatenate([[False], np.abs(step) > deadband])
    direction = np.concatenate([[0.0], np.sign(step)])[moved]
    r, x = readings[moved], dev[moved]
    if not len(r):
        return None
    labels = _targets(r)
    stats = []  # (mean↑, s↑, n↑, mean↓, s↓, n↓) per target
    for t in np.unique(labels):
        up = x[(labels == t) & (direction > 0)]
        down = x[(labels == t) & (direction < 0)]
        if len(up) >= MIN_APPROACHES and len(down) >= MIN_APPROACHES:
            stats.append(
                (up.mean(), up.std(ddof=1), len(up), down.mean(), down.std(ddof=1), len(down))
            )
    if not stats:
        return None
    s = np.array(stats)
    mu, su, nu, md, sd, nd = s.T
    b = mu - md
    r_i = np.maximum.reduce([2 * su + 2 * sd + np.abs(b), 4 * su, 4 * sd])
    hi = np.maximum(mu + 2 * su, md + 2 * sd)
    lo = np.minimum(mu - 2 * su, md - 2 * sd)
    return LegPositioning(
        leg,
        len(s),
        int(nu.sum() + nd.sum()),
        float(hi.max() - lo.min()),
        float((mu + 2 * su).max() - (mu - 2 * su).min()),
        float((md + 2 * sd).max() - (md - 2 * sd).min()),
        float(r_i.max()),
        float(np.abs(b).max()),
        float(b.mean()),
        float(np.sqrt(np.sum(su**2 / nu + sd**2 / nd)) / len(b)),
        float(max(mu.max(), md.max()) - min(mu.min(), md.min())),
        float(np.ptp(mu)),
        float(np.ptp(md)),
        float(np.ptp((mu + md) / 2)),
    )


def leg_positioning(model: LegModel, meas) -> list[LegPositioning]:
    """The figures of every leg that has bidirectional approaches in ``meas`` (module
    docstring); legs without are left out."""
    if len(meas) < 2:
        return []
    dev = deviations(model, meas)
    data = model.data(meas.readings, meas.position, meas.rotations.as_matrix(), meas.t)
    band = deadband_mm(data)
    out = []
    for k in range(6):
        fig = leg_figures(k + 1, meas.readings[:, k], dev[:, k], band)
        if fig is not None:
            out.append(fig)
    return out
