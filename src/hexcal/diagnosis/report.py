"""One self-contained HTML page of a diagnosis sequence: Model 42, + an effect, … until the
verdict is ``none`` (or the steps run out).

Self-contained means one file with no external resource: inline CSS, no script, the PNG plots
embedded as base64 ``data:`` URIs, so the page can be mailed, archived next to the data, or
opened offline. Every section has a stable id (``verdict``, ``provenance``, ``step-1``,
``step-1-legs``, ``change-1-2`` …) and the layout has a fixed width with the same section order
whatever the data, so two reports of the same data opened in two windows line up row for row.
All text from the data passes through :func:`html.escape`.
"""

from __future__ import annotations

import hashlib
import tempfile
from collections.abc import Callable, Mapping, Sequence
from datetime import datetime, timezone
from pathlib import Path

import hexcal
from hexcal.diagnosis.compare_plots import before_after_job, pose_error_job
from hexcal.diagnosis.diagnose import Diagnosis
from hexcal.diagnosis.figure_pool import FigureJob, draw_all
from hexcal.diagnosis.metrology import of_diagnosis
from hexcal.diagnosis.metrology_html import metrology_section
from hexcal.diagnosis.plots import plot_jobs
from hexcal.diagnosis.report_html import esc, figure, finite, for_any_width, num, stat, um
from hexcal.diagnosis.report_pointer import pointer_section
from hexcal.diagnosis.report_style import CSS
from hexcal.diagnosis.report_tables import (
    candidate_table,
    fit_table,
    leg_table,
    param_table,
    where_table,
)
from hexcal.diagnosis.summary import GLOSSARY, plain_summary
from hexcal.effects import get_effect
from hexcal.estimate.accuracy import floor_words
from hexcal.io.fileio import OutputFileError, write_error, write_text_atomic
from hexcal.vocabulary import Outcome, Verdict

#: Plot order in the report: the overview first, then one figure per suspect quantity.
REPORT_PLOTS = (
    (
        "per_leg_rms.png",
        "RMS per leg",
        "Bars above the grey floor bar: that leg carries more than noise.",
    ),
    (
        "predicted_vs_measured.png",
        "Residuals relative to the noise floor",
        "At the floor the histogram follows the black N(0, 1) curve and the Q–Q points the diagonal.",
    ),
    (
        "residuals_vs_reading.png",
        "Against the leg reading",
        "A slope is an encoder gain error; a ripple, the lead screw.",
    ),
    (
        "residuals_vs_motion.png",
        "By direction of last motion",
        "A step between retracting and extending is backlash.",
    ),
    ("residuals_vs_force.png", "Against the axial leg force", "A slope is leg compliance."),
    (
        "residuals_vs_temperature.png",
        "Against temperature",
        "A trend, growing with leg length, is thermal expansion.",
    ),
    (
        "residuals_vs_time.png",
        "Against time",
        "A drift the temperature does not follow points at the tracker or the mount.",
    ),
    (
        "residuals_vs_pose.png",
        "Against the platform pose",
        "Structure confined to part of the workspace: a local defect.",
    ),
    (
        "residuals_vs_direction.png",
        "Against the leg direction",
        "A trend with the leg's angle points at a joint.",
    ),
    (
        "periodogram.png",
        "Periodogram against the reading",
        "A peak above the dotted noise level at the pitch is the lead screw.",
    ),
    (
        "residuals_vs_covariate.png",
        "Against the covariate it follows",
        "The quantity an unexplained residual follows, with the running median per leg.",
    ),
)

#: The quantity on the before/after figure's second row, per effect added.
BETRAYS = {
    "gain": "reading",
    "leadscrew": "reading modulo the pitch",
    "backlash": "direction of last motion",
    "thermal": "temperature",
    "compliance": "axial force",
    "offset": "leg",
}


#: The verdict's CSS class and header label; any other verdict names an effect (or outliers).
_VERDICT_CLASS: dict[Verdict, str] = {
    Outcome.NONE: "v-none",
    Outcome.UNEXPLAINED: "v-unexplained",
    Outcome.NOISE_UNDERSTATED: "v-unexplained",
}
_VERDICT_LABEL: dict[Verdict, str] = {
    Outcome.NONE: "verdict — nothing missing",
    Outcome.UNEXPLAINED: "verdict — unexplained residual",
    Outcome.NOISE_UNDERSTATED: "verdict — the stated noise looks too low",
}


def _verdict_class(verdict: Verdict) -> str:
    return _VERDICT_CLASS.get(verdict, "v-effect")


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _hash(full: str) -> str:
    """A digest shortened to its ends; the whole value on hover (title) and in the copied text
    (a visually hidden copy)."""
    short = f"{full[:12]}…{full[-6:]}"
    return (
        f'<code class="hash" title="{esc(full)}"><span class="h-short" aria-hidden="true">'
        f'{esc(short)}</span><span class="h-full">{esc(full)}</span></code>'
    )


def _path(p: Path) -> str:
    """A path that may wrap after its separators, never inside a name."""
    return "/<wbr>".join(esc(part) for part in str(p).split("/"))


def _added(before: Diagnosis, after: Diagnosis) -> list[str]:
    return [e for e in after.effects if e not in before.effects]


# --- the header --------------------------------------------------------------------------------


def explanation(diags: Sequence[Diagnosis]) -> str:
    """One sentence on the last step's verdict (plain text)."""
    d = diags[-1]
    fit = d.fit
    floor = f"{um(d.noise_floor_mm)} µm" + (" (estimated)" if d.floor_estimated else "")
    if d.verdict == Outcome.NONE:
        text = (
            f"{fit.model_name} describes these data to the noise floor: held-out RMS "
            f"{um(fit.cv_rms_mm)} µm against a floor of {floor} (χ²/dof {d.chi2_per_dof:.2f})"
        )
        if len(diags) > 1:
            first = diags[0]
            added = _added(first, d)
            if added:
                text += (
                    f", once {' and '.join(added)} was added to {first.fit.model_name}, which left "
                    f"{um(first.fit.cv_rms_mm)} µm"
                )
        return text + "."
    if d.verdict == Outcome.UNEXPLAINED:
        lead = None if d.exploration is None else d.exploration.lead
        points = (
            f"; it follows the {lead.covariate.label} ({100 * lead.share:.0f} % of the excess)"
            if lead is not None
            else ""
        )
        return (
            f"{fit.model_name} leaves a residual above the noise floor (held-out RMS {um(fit.cv_rms_mm)} µm, "
            f"floor {floor}, χ²/dof {d.chi2_per_dof:.2f}) that no catalogue effect explains; "
            f"{d.where.get('summary', '')}{points}."
        )
    if d.verdict == Outcome.NOISE_UNDERSTATED:
        return (
            f"{fit.model_name} leaves a residual {d.noise_factor:.2f}× the stated noise, spread "
            "evenly over legs, steps, time, the workspace and every covariate: the stated noise "
            f"looks about {d.noise_factor:.1f}× too low (held-out RMS {um(fit.cv_rms_mm)} µm, "
            f"floor {floor})."
        )
    if d.verdict == Outcome.OUTLIERS:
        return (
            f"{len(d.outliers)} poses are gross outliers no model explains; without them "
            f"{fit.model_name} is at the noise floor (held-out RMS {um(fit.cv_rms_mm)} µm, floor "
            f"{floor})."
        )
    c = d.candidate(d.verdict)
    if c is None or c.refit is None:
        return f"{fit.model_name} is missing {d.verdict}."
    share = f" and explains {100 * c.explained:.0f} % of the excess" if finite(c.explained) else ""
    alike = f" ({' and '.join(d.alike)} fit{'s' * (len(d.alike) == 1)} alike)" if d.alike else ""
    return (
        f"{fit.model_name} is missing {d.verdict}{alike}: adding it lowers the held-out RMS from "
        f"{um(fit.cv_rms_mm)} to {um(c.cv_rms_mm_after)} µm (floor {floor}) with ΔBIC "
        f"{stat(c.delta_bic)}{share}."
    )


def _header(diags: Sequence[Diagnosis]) -> str:
    d = diags[-1]
    chips = []
    for i, s in enumerate(diags, 1):
        if i > 1:
            chips.append('<li class="arrow">→</li>')
        chips.append(
            f'<li class="chip {_verdict_class(s.verdict)}"><a href="#step-{i}" style="color:inherit">'
            f"{esc(s.fit.model_name)}</a>: {esc(s.verdict)} · {um(s.fit.cv_rms_mm)} µm</li>"
        )
    label = _VERDICT_LABEL.get(d.verdict, "verdict — effect missing from the model")
    # A sentence first; the verdict's word beside its label, not alone in big type.
    return (
        f'<header id="verdict" class="verdict {_verdict_class(d.verdict)}">'
        f"{_plain(diags)}"
        f'<div class="label">{esc(label)} · {esc(d.fit.model_name)}: '
        f'<span class="badge">{esc(d.verdict)}</span></div>'
        f'<ol class="path" id="path">{"".join(chips)}</ol>'
        f'<p class="muted" id="statistics">In statistics: {esc(explanation(diags))}</p></header>'
    )


def _accuracy(diags: Sequence[Diagnosis], tmp: Path | None) -> str:
    """Pose accuracy, the number a lab reports: the drawing's, then each model's on held-out
    poses, beside the floor the noise alone gives; the map of the error over the workspace."""
    rows = []
    first = diags[0].design_accuracy
    accs = ([first] if first is not None else []) + [d.accuracy for d in diags if d.accuracy]
    for a in accs:
        rows.append(
            f"<tr><td>{esc(a.model)}</td><td>{'held-out' if a.heldout else 'all poses'}</td>"
            f'<td class="num">{um(a.leg_rms_mm)}</td>'
            f'<td class="num">{um(a.position_rms_mm)}</td><td class="num">{um(a.position_p95_mm)}</td>'
            f'<td class="num">{um(a.position_max_mm)}</td>'
            f'<td class="num">{num(a.orientation_rms_deg, ".4f")}</td>'
            f'<td class="num">{num(a.orientation_p95_deg, ".4f")}</td></tr>'
        )
    last = diags[-1].accuracy
    if last is not None and last.floor_position_rms_mm is not None:
        rows.append(
            f'<tr class="muted"><td>{"estimated floor" if last.floor_estimated else "noise floor"}'
            "</td><td>the noise alone</td><td></td>"
            f'<td class="num">{um(last.floor_position_rms_mm)}</td><td></td><td></td>'
            f'<td class="num">{num(last.floor_orientation_rms_deg, ".4f")}</td><td></td></tr>'
        )
    fig = ""
    png = _drawn(tmp, _ACCURACY_MAP)
    if png is not None and accs:
        fig = figure(
            "accuracy-map",
            png,
            "Pose error over the workspace, before and after",
            "Each dot is a recorded pose seen from above, coloured by how far the pose the model "
            "computes from the six readings lies from the tracker's (one log scale for all "
            "panels): the drawing, then the models, each pose predicted by a fit that did not see it.",
        )
    return (
        '<section id="accuracy"><h2>Pose accuracy</h2>'
        '<p class="muted">Where the platform really is (the tracker) against where the model '
        "puts it from the six encoder readings: position error at the platform origin and "
        "orientation error, in µm and degrees.</p>"
        "<table><tr><th>model</th><th>poses</th><th>leg RMS µm</th><th>position RMS µm</th>"
        "<th>95 % µm</th><th>max µm</th><th>orientation RMS °</th><th>95 % °</th></tr>"
        + "".join(rows)
        + "</table>"
        + fig
        + "</section>"
    )


def _plain(diags: Sequence[Diagnosis]) -> str:
    """The findings in plain words (:mod:`hexcal.diagnosis.summary`), before any statistic."""
    said = plain_summary(diags)
    body = "".join(
        f'<p class="{"lead" if i == 0 else "why"}">{esc(s)}</p>' for i, s in enumerate(said)
    )
    return f'<div id="summary">{body}</div>'


def _glossary() -> str:
    items = "".join(f"<dt>{esc(term)}</dt><dd>{esc(text)}</dd>" for term, text in GLOSSARY.items())
    return f'<section id="glossary"><h2>Glossary</h2><dl class="glossary">{items}</dl></section>'


def _nav(diags: Sequence[Diagnosis]) -> str:
    items = [
        '<li><a href="#accuracy">Pose accuracy</a></li>',
        '<li><a href="#metrology">Metrology</a></li>',
    ]
    for i, d in enumerate(diags, 1):
        items.append(
            f'<li><a href="#step-{i}">Step {i}: {esc(d.fit.model_name)} — {esc(d.verdict)}</a></li>'
        )
        if i < len(diags):
            items.append(f'<li><a href="#change-{i}-{i + 1}">Change {i} → {i + 1}</a></li>')
    items.append('<li><a href="#provenance">Provenance</a></li>')
    items.append('<li><a href="#glossary">Glossary</a></li>')
    return f'<nav id="contents" class="muted"><ol>{"".join(items)}</ol></nav>'


def _provenance(diags: Sequence[Diagnosis], inputs: Mapping[str, Path]) -> str:
    rows = [
        ("hexcal version", esc(hexcal.__version__)),
        ("report written (UTC)", esc(datetime.now(timezone.utc).isoformat(timespec="seconds"))),
    ]
    for label, p in inputs.items():
        p = Path(p)
        try:
            digest = f"sha256 {_hash(_sha256(p))}"
        except OSError as exc:
            digest = f'<span class="err">not readable: {esc(exc.strerror or exc)}</span>'
        rows.append((f"input: {esc(label)}", f"<code>{_path(p)}</code><br>{digest}"))
    rows.append(("models", " → ".join(esc(d.fit.model_name) for d in diags)))
    outside = {  # effects from outside the catalogue, fitted or scored: where their code came from
        e: get_effect(e).source.text()
        for d in diags
        for e in (*d.effects, *(c.effect for c in d.candidates))
        if get_effect(e).source.kind != "catalogue"
    }
    if outside:
        rows.append(
            ("effects loaded", "<br>".join(f"{esc(n)}: {esc(t)}" for n, t in outside.items()))
        )
    sources = list(dict.fromkeys(d.floor_source for d in diags))
    rows.append(("noise floor", "<br>".join(esc(s) for s in sources)))
    m = len(diags[0].problem.meas)
    rows.append(("poses", f"{m} ({6 * m} leg residuals)"))
    body = "".join(f"<dt>{k}</dt><dd>{v}</dd>" for k, v in rows)
    return f'<section id="provenance"><h2>Provenance</h2><dl class="kv">{body}</dl></section>'


# --- one step ----------------------------------------------------------------------------------


def _plots(d: Diagnosis, sid: str, tmp: Path) -> str:
    figs = []
    for name, title, caption in REPORT_PLOTS:
        stem = name.removesuffix(".png")
        skipped = (
            "the measurements have no temperature column" if "temperature" in name else "not drawn"
        )
        if "covariate" in name:
            skipped = "drawn when an unexplained residual follows a covariate"
        png = _drawn(tmp, f"{sid}/{name}")
        figs.append(figure(f"{sid}-plot-{stem}", png, title, caption, skipped))
    return f'<div id="{sid}-plots"><h3>Residual plots</h3>{"".join(figs)}</div>'


def _step(d: Diagnosis, i: int, tmp: Path | None) -> str:
    sid = f"step-{i}"
    plots = _plots(d, sid, tmp) if tmp is not None else f'<div id="{sid}-plots"></div>'
    colour = {"v-none": "ok", "v-effect": "warn", "v-unexplained": "err"}[_verdict_class(d.verdict)]
    return (
        f'<section id="{sid}"><h2>Step {i} · {esc(d.fit.model_name)} — verdict '
        f'<span class="{colour}">{esc(d.verdict)}</span></h2>'
        + fit_table(d, sid)
        + leg_table(d, sid)
        + candidate_table(d, sid)
        + where_table(d, sid)
        + pointer_section(d, sid)
        + param_table(d, sid)
        + plots
        + "</section>"
    )


def _change(a: Diagnosis, b: Diagnosis, i: int, tmp: Path | None) -> str:
    cid = f"change-{i}-{i + 1}"
    added = _added(a, b)
    what = " + ".join(added) if added else "no effect"
    line = (
        f"held-out RMS {um(a.fit.cv_rms_mm)} → {um(b.fit.cv_rms_mm)} µm "
        f"({floor_words(b.floor_estimated)} {um(b.noise_floor_mm)} µm)"
    )
    betrays = BETRAYS.get(added[0], "reading") if added else "reading"
    fig = ""
    png = _drawn(tmp, f"{cid}/{_BEFORE_AFTER}")
    if png is not None:
        fig = figure(
            f"{cid}-figure",
            png,
            f"Before and after adding {what}",
            f"Top: held-out RMS per leg against the noise floor. Bottom: the residual against the "
            f"{betrays}, which betrays {added[0] if added else 'a missing effect'}; after the change it "
            "should be flat.",
        )
    return (
        f'<section id="{cid}" class="change"><h2>Change {i} → {i + 1}: {esc(a.fit.model_name)} → '
        f'{esc(b.fit.model_name)}</h2><p class="line">{esc(line)}</p>{fig}</section>'
    )


#: Where the figures are drawn, under the report's temporary folder.
_ACCURACY_MAP = "accuracy/pose_error.png"
_BEFORE_AFTER = "before_after.png"


def _drawn(tmp: Path | None, name: str) -> Path | None:
    """The figure ``name`` drawn under ``tmp`` by :func:`figure_jobs`, or None (not drawn)."""
    if tmp is None:
        return None
    path = tmp / name
    return path if path.is_file() else None


def figure_jobs(diags: Sequence[Diagnosis], tmp: Path) -> list[FigureJob]:
    """Every figure of the report on ``diags``, to draw under ``tmp`` before the page is put
    together: the pose-error map, each change's before/after, each step's residual plots. All
    are drawn at once so that they share the cores (:func:`~hexcal.diagnosis.figure_pool.draw_all`)."""
    jobs = []
    if diags[0].design_accuracy is not None or any(d.accuracy for d in diags):
        jobs.append(pose_error_job(list(diags), tmp / _ACCURACY_MAP))
    jobs += [
        before_after_job(diags[i - 1], diags[i], tmp / f"change-{i}-{i + 1}" / _BEFORE_AFTER)
        for i in range(1, len(diags))
    ]
    for i, d in enumerate(diags, 1):
        jobs += plot_jobs(d, tmp / f"step-{i}")
    return jobs


def _ignore(tick: Callable[[], None]) -> Callable[[Path], None]:
    """``tick`` called with a figure's path, which it does not need."""
    return lambda _path: tick()


def figure_count(diags: Sequence[Diagnosis]) -> int:
    """How many figures :func:`write_report` draws for ``diags`` (a progress bar's length)."""
    from hexcal.diagnosis.plots import plot_names

    has_map = diags[0].design_accuracy is not None or any(d.accuracy for d in diags)
    return int(has_map) + len(diags) - 1 + sum(len(plot_names(d)) for d in diags)


def render_report(
    diags: Sequence[Diagnosis],
    inputs: Mapping[str, Path],
    plots: bool = True,
    limits: Sequence[str] = (),
    on_figure: Callable[[], None] | None = None,
    limits_advice: str = "",
) -> str:
    """The report's HTML text (see :func:`write_report`)."""
    if not diags:
        raise ValueError("write_report needs at least one Diagnosis")
    d = diags[-1]
    parts = [
        '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>hexcal diagnosis — {esc(d.fit.model_name)}: {esc(d.verdict)}</title>",
        f"<style>{CSS}</style></head><body><main>",
        _header(diags),
        _nav(diags),
    ]
    if limits:
        items = "".join(f"<li>{esc(line)}</li>" for line in limits)
        parts.append(
            "<section id=\"limits\"><h2>Poses at a stroke's end or a joint's limit</h2>"
            f'<ul>{items}</ul><p class="muted">{esc(_sentence(limits_advice))}</p></section>'
        )
    with tempfile.TemporaryDirectory(prefix="hexcal-report-") as t:
        tmp = Path(t) if plots else None
        if tmp is not None:
            draw_all(figure_jobs(diags, tmp), None if on_figure is None else _ignore(on_figure))
        parts.append(_accuracy(diags, tmp))
        parts.append(metrology_section(of_diagnosis(d)))
        for i, step in enumerate(diags, 1):
            if i > 1:
                parts.append(_change(diags[i - 2], step, i - 1, tmp))
            parts.append(_step(step, i, tmp))
    parts.append(_provenance(diags, inputs))
    parts.append(_glossary())
    parts.append(
        f'<footer id="footer" class="muted">hexcal {esc(hexcal.__version__)} · residual = reading − '
        "predicted reading; held-out = predicted by a fit that did not see the pose.</footer>"
        "</main></body></html>\n"
    )
    return for_any_width("\n".join(parts))


def _sentence(advice: str) -> str:
    """The limits' advice as a sentence (capitalised, a full stop)."""
    from hexcal.diagnosis.limits import LEAVE_OUT

    text = advice or LEAVE_OUT
    return text[:1].upper() + text[1:] + "."


def write_report(
    diags: Sequence[Diagnosis],
    path: Path,
    inputs: Mapping[str, Path],
    plots: bool = True,
    limits: Sequence[str] = (),
    on_figure: Callable[[], None] | None = None,
    limits_advice: str = "",
) -> Path:
    """Write ONE self-contained HTML report of a diagnosis sequence to ``path`` (atomically).

    ``diags``: the steps in order (e.g. Model 42, then + backlash, … until the verdict is
    ``none``); between consecutive steps a before/after figure is drawn. ``inputs``: label →
    input file, listed with its SHA-256. ``plots=False`` leaves the figures out (a quick,
    tables-only page). ``on_figure`` is called as each figure is drawn (a progress bar of
    :func:`figure_count` figures). ``limits``: the lines of the poses at a stroke's end or a
    joint's limit, ``limits_advice`` what to do with them
    (:func:`hexcal.diagnosis.limits.advice`; by default, leave them out).
    Returns ``path``.
    """
    path = Path(path)
    try:
        text = render_report(diags, inputs, plots, limits, on_figure, limits_advice)
    except OSError as exc:  # a figure, in the temporary folder the report draws in
        if not isinstance(exc, OutputFileError):
            exc = write_error(exc, exc.filename or tempfile.gettempdir())
        raise OutputFileError(
            f"{path}: not written: its figures could not be drawn ({exc})", path
        ) from None
    write_text_atomic(path, text)
    return path
