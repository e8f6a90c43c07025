"""Two steps of a diagnosis chain compared on the same poses.

Each diagnosis sets gross outliers aside anew under its own model: an effect that explains the
poses a model without it could not fit readmits them. The held-out RMS of the step after is
then over more poses (or fewer) than the step before's, and the two figures are not the same
measure: a readmitted pose deep in a dent raises the RMS although the added effect predicts
every pose better. The step before's model, refitted on the step after's poses, gives the
figure the step after's is to be read against.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from hexcal.estimate.effect_fit import fit_model

if TYPE_CHECKING:
    from hexcal.diagnosis.diagnose import Diagnosis


def same_poses(before: Diagnosis, after: Diagnosis) -> bool:
    """Both diagnoses were computed on the same poses (they set aside the same ones)."""
    return sorted(before.outlier_ids) == sorted(after.outlier_ids)


def before_on_after_poses(before: Diagnosis, after: Diagnosis) -> float:
    """mm, the held-out RMS of ``before``'s model refitted (and cross-validated) on the poses
    ``after`` kept; ``after``'s own figure where the poses are the same, NaN where that model
    cannot be fitted there."""
    if same_poses(before, after):
        return float(before.fit.cv_rms_mm)
    try:
        fit = fit_model(after.problem, before.fit.effects)
    except (ValueError, np.linalg.LinAlgError):
        return float("nan")
    return float(fit.cv_rms_mm)


def compare_steps(before: Diagnosis, after: Diagnosis) -> None:
    """Where the two steps kept other poses, record in ``after`` the step before's held-out RMS
    on ``after``'s poses (:attr:`~hexcal.diagnosis.diagnose.Diagnosis.cv_rms_before_mm`) and
    say so in its notes, so that the fall (or rise) between the steps is read on one set of
    poses."""
    if same_poses(before, after):
        return
    ref = before_on_after_poses(before, after)
    after.cv_rms_before_mm = ref
    kept = sorted(set(before.outlier_ids) - set(after.outlier_ids))
    dropped = sorted(set(after.outlier_ids) - set(before.outlier_ids))
    parts = []
    if kept:
        parts.append(f"{_poses(kept)} set aside at the step before {_are(kept)} kept now")
    if dropped:
        parts.append(f"{_poses(dropped)} {_are(dropped)} set aside now")
    if not np.isfinite(ref):
        figure = "the model before cannot be fitted on them"
    else:
        figure = (
            f"on these {len(after.problem.meas)} poses the model before predicts held-out "
            f"poses to {1000 * ref:.2f} µm RMS, this one to {1000 * after.fit.cv_rms_mm:.2f} µm"
        )
    after.notes.append("; ".join(parts) + f": {figure}.")


def _poses(ids: list[int]) -> str:
    shown = ", ".join(str(i) for i in ids[:8]) + (", …" if len(ids) > 8 else "")
    return f"pose{'s' * (len(ids) > 1)} {shown}"


def _are(ids: list[int]) -> str:
    return "are" if len(ids) > 1 else "is"
