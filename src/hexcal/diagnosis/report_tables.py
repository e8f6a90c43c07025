"""The tables of one diagnosis step in the HTML report: the fit against the noise floor, each
leg's residual, the catalogue's candidates ranked, where the residual concentrates, and the
fitted parameters with their notes and strong correlations. Each is a ``<div>`` whose id starts
with the step's (``step-1-fit`` …)."""

from __future__ import annotations

import re
from collections.abc import Sequence

import numpy as np

from hexcal.diagnosis.diagnose import Diagnosis
from hexcal.diagnosis.report_html import esc, finite, num, stat, um, value_ci
from hexcal.diagnosis.text import RANKED_LEGEND
from hexcal.estimate.effect_fit import ParamRow


def floor_per_leg_mm(d: Diagnosis) -> np.ndarray:
    """(6,) mm: RMS of the noise floor of each leg's residuals."""
    return np.sqrt(np.mean(d.floor_per_residual**2, axis=0))


def fit_table(d: Diagnosis, sid: str) -> str:
    f = d.fit
    ratio = f.cv_rms_mm / d.noise_floor_mm if d.noise_floor_mm > 0 else float("nan")
    cls = "ok" if not d.excess_significant else "err"
    cells = [
        ("RMS (in-sample)", f"{um(f.rms_mm)} µm"),
        ("held-out RMS (random 5-fold)", f"{um(f.cv_rms_mm)} µm"),
        ("held-out RMS (blocked in time)", f"{um(f.cv_blocked_rms_mm)} µm"),
        ("noise floor", f"{um(d.noise_floor_mm)} µm"),
        ("held-out / floor", f'<span class="{cls}">{num(ratio, ".2f")}</span>'),
        (
            "χ²/dof (1 at the floor)",
            f'<span class="{cls}">{num(d.chi2_per_dof, ".2f")}</span>'
            + (" — excess significant" if d.excess_significant else " — within noise"),
        ),
    ]
    # One row per figure: six long headers over one row of numbers stood 4 lines tall at 768 px.
    rows = "".join(f'<tr><td>{esc(k)}</td><td class="num">{v}</td></tr>' for k, v in cells)
    return (
        f'<div id="{sid}-fit"><h3>Fit against the noise floor</h3>'
        '<table class="narrow"><tr><th>figure</th><th class="num">value</th></tr>'
        f"{rows}</table>"
        f'<p class="muted">Noise floor: {esc(d.floor_source)}.</p></div>'
    )


def leg_table(d: Diagnosis, sid: str) -> str:
    f = d.fit
    floor = floor_per_leg_mm(d)
    held = f.cv_rms_per_leg if f.cv_residuals is not None else np.full(6, np.nan)
    blocked = (
        np.sqrt(np.mean(f.cv_blocked_residuals**2, axis=0))
        if f.cv_blocked_residuals is not None
        else np.full(6, np.nan)
    )
    excess = {g["group"]: g for g in d.where.get("legs", [])}
    scale = (
        max(float(np.nanmax(held)) if np.isfinite(held).any() else 0.0, float(floor.max())) * 1.1
    )
    rows = []
    for k in range(6):
        g = excess.get(f"leg {k + 1}")
        ratio = f"{g['excess_ratio']:.1f}×" if g else "—"
        mark = ' <span class="err">stands out</span>' if g and g["stands_out"] else ""
        w = 100 * held[k] / scale if np.isfinite(held[k]) and scale > 0 else 0.0
        fl = 100 * floor[k] / scale if scale > 0 else 0.0
        colour = (
            "#c62828"
            if held[k] > 1.5 * floor[k]
            else ("#e69500" if held[k] > 1.15 * floor[k] else "#2e7d32")
        )
        bar = (
            f'<div class="bar" title="held-out RMS; black tick: noise floor"><span style="width:{w:.1f}%;'
            f'background:{colour}"></span><i style="left:{fl:.1f}%"></i></div>'
        )
        rows.append(
            f'<tr><td>leg {k + 1}</td><td class="num">{um(f.rms_per_leg[k])}</td>'
            f'<td class="num">{um(held[k])}</td><td class="num">{um(blocked[k])}</td>'
            f'<td class="num">{um(floor[k])}</td><td class="num">{ratio}{mark}</td><td>{bar}</td></tr>'
        )
    return (
        f'<div id="{sid}-legs"><h3>Per leg</h3><table>'
        '<tr><th>leg</th><th class="num">RMS µm</th><th class="num">held-out µm</th>'
        '<th class="num">blocked held-out µm</th><th class="num">floor µm</th>'
        '<th class="num">mean (r/floor)²</th><th class="bars">held-out (bar), floor (tick)</th></tr>'
        + "".join(rows)
        + "</table></div>"
    )


def candidate_table(d: Diagnosis, sid: str) -> str:
    rows = []
    for c in d.candidates:
        cls = (
            "win"
            if c.effect == d.verdict
            else ("off" if not (c.available and c.identifiable) else "")
        )
        why = c.reason
        if c.available and not c.identifiable and c.separating_motion and "record" not in why:
            why += f"; record {c.separating_motion}"
        if c.refit is not None and c.refit.nonphysical():
            why = (
                (why + "; " if why else "")
                + "outside its plausible range: "
                + ", ".join(p.name for p in c.refit.nonphysical())
            )
        ident = "yes" if c.identifiable else ("n/a" if not c.available else "no")
        rows.append(
            f'<tr class="{cls}"><td>{esc(c.effect)}</td><td class="num">{stat(d.score_shown(c))}</td>'
            f'<td class="num">{stat(c.delta_bic)}</td>'
            f'<td class="num">{num(100 * c.explained, ".0f") + " %" if finite(c.explained) else "—"}</td>'
            f'<td class="num">{um(c.cv_rms_mm_after)}</td><td>{esc(ident)}</td><td>{esc(why)}</td></tr>'
        )
    if not rows:
        rows.append(
            '<tr><td colspan="7" class="muted">every catalogue effect is already in the model</td></tr>'
        )
    return (
        f'<div id="{sid}-candidates"><h3>What could be missing: the catalogue, ranked</h3>'
        '<table class="ranked"><tr><th>effect</th><th class="num">score Δχ²</th><th class="num">ΔBIC</th>'
        '<th class="num">explains</th><th class="num"><span class="nowrap">held-out after</span> µm</th><th>identifiable</th>'
        "<th>reason / note</th></tr>" + "".join(rows) + "</table>"
        f'<p class="muted">{esc(RANKED_LEGEND)}.</p></div>'
    )


def where_table(d: Diagnosis, sid: str) -> str:
    w = d.where
    groups = [
        g
        for key in ("legs", "steps", "time", "region", "leg_region")
        for g in w.get(key, [])
        if g["stands_out"]
    ]
    groups.sort(key=lambda g: -g["excess_ratio"])
    standout = (
        "".join(
            f'<tr><td>{esc(g["group"])}</td><td class="num">{g["n"]}</td><td class="num">{g["excess_ratio"]:.1f}×</td></tr>'
            for g in groups[:8]
        )
        or '<tr><td colspan="3" class="muted">no group stands out</td></tr>'
    )
    worst = "".join(
        f'<tr><td class="num">{p["pose_id"]}</td><td>{esc(p["step"])}</td>'
        f'<td class="num">{p["excess_ratio"]:.1f}×</td><td class="num">{p["worst_leg"]}</td></tr>'
        for p in w.get("worst_poses", [])
    )
    return (
        f'<div id="{sid}-where"><h3>Where the residual concentrates</h3>'
        f"<p>{esc(w.get('summary', ''))}</p>"
        # Side by side on a grid, one column on a narrow page (report_style's .pair).
        '<div class="pair"><div>'
        '<table><colgroup><col><col style="width:16%"><col style="width:24%"></colgroup>'
        '<tr><th>group standing out</th><th class="num">n</th><th class="num">mean (r/floor)²</th></tr>'
        f"{standout}</table></div><div>"
        '<table><tr><th class="num">worst pose</th><th>step</th><th class="num">mean (r/floor)²</th>'
        f'<th class="num">worst leg</th></tr>{worst}</table></div></div></div>'
    )


def _param_notes(p: ParamRow, notes: Sequence[str]) -> list[str]:
    """The fit's notes that name parameter ``p`` (a whole name: ``a1.x`` is not ``a1.xy``)."""
    pat = re.compile(rf"(?<![\w.]){re.escape(p.name)}(?![\w])")
    return [n for n in notes if pat.search(n)]


def _is_geometry(name: str) -> bool:
    return bool(re.fullmatch(r"[ab][1-6]\.[xyz]", name))


def param_rows(params: Sequence[ParamRow], notes: Sequence[str]) -> str:
    out = []
    for p in params:
        bad = (not p.physical) or p.status != "ok"
        rng = f"[{num(p.plausible[0], 'g')}, {num(p.plausible[1], 'g')}]" if p.plausible else "—"
        flag = []
        if not p.physical:
            flag.append("outside its plausible range")
        if p.status != "ok":
            flag.append(p.status)
        out.append(
            f'<tr class="{"bad" if bad else ""}"><td><code>{esc(p.name)}</code></td>'
            f'<td class="num">{esc(value_ci(p))}</td><td class="num">{esc(num(p.sigma, ".2g"))}</td>'
            f"<td>{esc(p.unit)}</td><td>{esc(rng)}</td><td>{esc(', '.join(flag) or 'ok')}</td></tr>"
        )
        if bad:
            text = _param_notes(p, notes) or [
                f"status {p.status}" if p.status != "ok" else "outside its plausible range"
            ]
            out.append(
                f'<tr class="note"><td></td><td colspan="5">{"<br>".join(esc(t) for t in text)}</td></tr>'
            )
    return "".join(out)


def param_table(d: Diagnosis, sid: str) -> str:
    f = d.fit
    notes = list(dict.fromkeys(d.notes + f.notes))
    head = (
        '<table><colgroup><col style="width:18%"><col style="width:22%"><col style="width:12%">'
        '<col style="width:10%"><col style="width:16%"><col></colgroup>'
        '<tr><th>parameter</th><th class="num">value ± 95 %</th><th class="num">σ</th><th>unit</th>'
        "<th>plausible range</th><th>status</th></tr>"
    )
    # Geometry (36 coordinates) is long and rarely the story: it folds away unless flagged.
    main = [p for p in f.params if not _is_geometry(p.name) or not p.physical or p.status != "ok"]
    geometry = [p for p in f.params if _is_geometry(p.name)]
    corr = f.refinement.strong_correlations
    corr_html = (
        '<ul class="notes">'
        + "".join(
            f"<li><code>{esc(a)}</code> ↔ <code>{esc(b)}</code>: r = {num(r, '+.3f')}</li>"
            for a, b, r in corr
        )
        + "</ul>"
        if corr
        else '<p class="muted">none</p>'
    )
    note_html = (
        '<ul class="notes">' + "".join(f"<li>{esc(n)}</li>" for n in notes) + "</ul>"
        if notes
        else ""
    )
    return (
        f'<div id="{sid}-params"><h3>Parameters (offsets, effects, and any flagged geometry)</h3>'
        + head
        + param_rows(main, notes)
        + "</table>"
        + f"<details><summary>all {len(geometry)} geometry coordinates (mm)</summary>"
        + head
        + param_rows(geometry, notes)
        + "</table></details>"
        + f'<h3 id="{sid}-correlations">Strong correlations</h3>'
        + corr_html
        + (f'<h3 id="{sid}-notes">Notes</h3>' + note_html if note_html else "")
        + "</div>"
    )
