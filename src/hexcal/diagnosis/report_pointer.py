"""The report's "Where the residual points" section: the covariates an unexplained residual
follows (:mod:`hexcal.diagnosis.explorer`), each with the share of the excess it explains
alone and the shape that does it, and what the leading one points at."""

from __future__ import annotations

from hexcal.diagnosis.diagnose import Diagnosis
from hexcal.diagnosis.report_html import esc


def pointer_section(d: Diagnosis, sid: str) -> str:
    """The section of step ``sid`` (empty unless the step explored the covariates)."""
    x = d.exploration
    if x is None:
        return ""
    rows = (
        "".join(
            f"<tr><td>{esc(t.covariate.label)} <span class='muted'>({esc(t.covariate.name)})</span>"
            f"</td><td>{esc(t.shape.describe(t.covariate.unit))}</td>"
            f"<td>{esc(', '.join(map(str, t.shape.legs)))}</td>"
            f'<td class="num">{100 * t.share:.0f} %</td>'
            f'<td class="num">{t.score:.0f} / {t.threshold:.0f}</td></tr>'
            for t in x.leads[:6]
        )
        or '<tr><td colspan="5" class="muted">the residual follows none of the covariates</td></tr>'
    )
    lead = x.lead
    hint = (
        f"<p>The {esc(lead.covariate.label)} points at {esc(lead.points_at)}. "
        "<code>hexcal diagnose … --effect-file FILE.py</code> writes an effect with that shape: "
        "edit it to the physics you suspect, pass it back with <code>--effects FILE.py --add "
        f"{esc(lead.effect_name)}</code>, and watch the error fall.</p>"
        if lead is not None
        else "<p>No covariate of the library explains a significant share: look at the "
        "residual plots below.</p>"
    )
    return (
        f'<div id="{sid}-points"><h3>Where the residual points</h3>'
        "<p>The residual regressed on each covariate (the model's own parameters projected "
        "out); a covariate counts when its χ² beats the threshold over every shape tried.</p>"
        '<table><colgroup><col style="width:38%"><col style="width:22%"><col style="width:12%">'
        '<col style="width:12%"><col style="width:16%"></colgroup>'
        '<tr><th>covariate</th><th>shape</th><th>legs</th><th class="num">of the excess</th>'
        f'<th class="num">χ² / threshold</th></tr>{rows}</table>{hint}</div>'
    )
