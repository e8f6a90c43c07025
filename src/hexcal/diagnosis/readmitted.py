"""The explorer's leads tested on the poses their file would keep.

The explorer works on the poses the diagnosis kept, its gross outliers set aside. Loaded as an
effect file, a lead changes which poses are outliers: a dent's deepest poses, set aside under a
model without it, are fitted in-sample by a smooth shape along the stroke and readmitted. Its
held-out figure on the poses it saw then says nothing of the poses it lets back in, where a
shape fitted on the shoulders of the dent predicts the bottom worse than no shape at all.

So, before a lead is proposed where outliers were set aside, the next diagnosis is done as the
chain would do it: the outliers searched for again with the lead in the model, and, on the
poses then kept, the model with and without the lead cross-validated. A lead that predicts
those poses worse is not proposed ("never worse", issue 34), and the next is tried.
"""

from __future__ import annotations

import numpy as np

from hexcal.diagnosis.explorer import Exploration
from hexcal.diagnosis.lead_refit import lead_effect
from hexcal.diagnosis.outliers import Subset, find_outliers
from hexcal.estimate.effect_fit import Problem, fit_model

#: The leads, best first, tried on the poses their file would keep (each an outlier search).
N_READMITTED = 3


def check_readmitted(
    session: Problem, work: Problem, effects: tuple[str, ...], exploration: Exploration
) -> None:
    """Mark as not proposed (``worse``, with a note) each of the exploration's leads, best
    first, that predicts held-out poses worse on the poses a diagnosis with it would keep; stop
    at the first that does not (or whose poses kept are ``work``'s own). ``session``: the
    whole session's problem; ``work``: the poses the diagnosis kept (a :class:`Subset`)."""
    start = (
        np.setdiff1d(np.arange(len(session.meas)), work.rows) if isinstance(work, Subset) else None
    )
    for lead in exploration.leads[:N_READMITTED]:
        with lead_effect(session, lead) as name:
            search = find_outliers(session, (*effects, name), start)
            kept = search.problem
            rows = kept.rows if isinstance(kept, Subset) else np.arange(len(session.meas))
            if isinstance(work, Subset) and np.array_equal(rows, work.rows):
                return  # the same poses: the explorer's own figure stands
            try:
                cv_with = fit_model(kept, (*effects, name)).cv_rms_mm
                cv_without = fit_model(kept, effects).cv_rms_mm
            except (ValueError, np.linalg.LinAlgError) as exc:
                lead.worse = True
                lead.notes.append(
                    f"not proposed: its refit on the poses it would keep failed: {exc}"
                )
                exploration.notes.append(f"{lead.covariate.name}: " + lead.notes[-1])
                continue
        if cv_with < cv_without:
            return
        lead.worse = True
        change = _change(work, rows, len(session.meas))
        lead.notes.append(
            f"not proposed: with it {change}, and on those {len(rows)} poses it predicts "
            f"held-out poses worse than the model without it ({1000 * cv_without:.2f} → "
            f"{1000 * cv_with:.2f} µm RMS): it fits the poses it saw, not the ones it lets in"
        )
        exploration.notes.append(f"{lead.covariate.name}: " + lead.notes[-1])


def _change(work: Problem, rows: np.ndarray, m: int) -> str:
    """The change in the poses kept, in words."""
    before = set(work.rows.tolist()) if isinstance(work, Subset) else set(range(m))
    back, out = len(set(rows.tolist()) - before), len(before - set(rows.tolist()))
    parts = []
    if back:
        parts.append(f"{back} pose{'s' * (back > 1)} set aside as outliers would be kept")
    if out:
        parts.append(f"{out} other{'s' * (out > 1)} set aside")
    return " and ".join(parts)
