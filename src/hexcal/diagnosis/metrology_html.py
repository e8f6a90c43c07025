"""The metrology figures (:class:`~hexcal.diagnosis.metrology.Metrology`) as a section of the
HTML report: the poses' expanded uncertainty and its coverage, ISO 9283 per test pose, ISO
230-2 per leg. The same numbers as the text and ``--json``."""

from __future__ import annotations

from hexcal.diagnosis.metrology import Metrology
from hexcal.diagnosis.report_html import esc, um


def metrology_section(m: Metrology) -> str:
    """``<section id="metrology">``: uncertainty, ISO 9283, ISO 230-2 (docs/metrology.md)."""
    parts = [
        '<section id="metrology"><h2>Metrology</h2>',
        f'<p class="muted">{esc(m.model)}; how each figure is computed and which clauses of ISO '
        "9283, ISO 230-2 and the GUM it follows: docs/metrology.md.</p>",
    ]
    u = m.uncertainty
    if u is not None:
        d = u.to_dict(per_pose=False)
        cov = d["position_coverage_95"]
        parts.append(
            "<h3>Uncertainty of the computed pose (GUM, k = 2)</h3>"
            f'<p class="muted">Propagated from {esc(u.source)}.</p>'
            "<table><tr><th>position, mean µm</th><th>position, max µm</th>"
            "<th>orientation, mean °</th><th>orientation, max °</th>"
            "<th>errors inside their 95 % region</th></tr>"
            f'<tr><td class="num">{um(d["position_mean_mm"])}</td>'
            f'<td class="num">{um(d["position_max_mm"])}</td>'
            f'<td class="num">{d["orientation_mean_deg"]:.4f}</td>'
            f'<td class="num">{d["orientation_max_deg"]:.4f}</td>'
            f'<td class="num">{"—" if cov is None else f"{100 * cov:.1f} %"}</td></tr></table>'
        )
    parts.append("<h3>ISO 9283: pose accuracy and repeatability</h3>")
    if m.iso9283 is None:
        parts.append('<p class="muted">No iso9283 step in these poses.</p>')
    else:
        rows = "".join(
            f'<tr><td>{p.label}</td><td class="num">{p.visits}</td>'
            f'<td class="num">{um(p.ap_p_mm)}</td>'
            + "".join(f'<td class="num">{v:+.5f}</td>' for v in p.ap_deg)
            + f'<td class="num">{um(p.rp_l_mm)}</td>'
            + "".join(f'<td class="num">±{v:.5f}</td>' for v in p.rp_deg)
            + "</tr>"
            for p in m.iso9283.poses
        )
        parts.append(
            f'<p class="muted">{esc(m.iso9283.cube.text())}.</p>'
            "<table><tr><th>pose</th><th>cycles</th><th>AP_P µm</th><th>AP_a °</th>"
            "<th>AP_b °</th><th>AP_c °</th><th>RP_l µm</th><th>RP_a °</th><th>RP_b °</th>"
            f"<th>RP_c °</th></tr>{rows}</table>"
        )
    parts.append("<h3>ISO 230-2: positioning of each leg</h3>")
    if not m.iso230_2:
        parts.append(
            '<p class="muted">No leg came to one reading from both directions at least twice '
            "each.</p>"
        )
    else:
        rows = "".join(
            f'<tr><td>{p.leg}</td><td class="num">{p.targets}</td>'
            f'<td class="num">{p.approaches}</td><td class="num">{um(p.accuracy_mm)}</td>'
            f'<td class="num">{um(p.repeatability_mm)}</td><td class="num">{um(p.reversal_mm)}</td>'
            f'<td class="num">{1000 * p.mean_reversal_mm:+.1f} ± '
            f'{1000 * p.mean_reversal_sigma_mm:.1f}</td><td class="num">{um(p.systematic_mm)}</td>'
            f'<td class="num">{um(p.mean_bidirectional_mm)}</td></tr>'
            for p in m.iso230_2
        )
        parts.append(
            "<p class=\"muted\">Deviation: the leg's length from the tracker less the model's "
            "from its reading, backlash left out.</p>"
            "<table><tr><th>leg</th><th>targets</th><th>approaches</th><th>A µm</th>"
            "<th>R µm</th><th>B µm</th><th>B̄ ± σ µm</th><th>E µm</th>"
            f"<th>M µm</th></tr>{rows}</table>"
        )
    parts += [f'<p class="muted">{esc(n)}</p>' for n in m.notes]
    parts.append("</section>")
    return "".join(parts)
