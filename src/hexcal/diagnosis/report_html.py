"""HTML formatting shared by the report's sections (:mod:`hexcal.diagnosis.report`,
:mod:`~hexcal.diagnosis.report_tables`, :mod:`~hexcal.diagnosis.report_pointer`,
:mod:`~hexcal.diagnosis.metrology_html`): every text from the data escaped, numbers in µm with a
true minus sign, an em dash for a missing value, a figure embedded as a ``data:`` URI; and the
finished page's last pass (:func:`for_any_width`): numbers kept with their units, tables
labelled for the narrow layout."""

from __future__ import annotations

import base64
import html
import re
from collections.abc import Callable
from pathlib import Path
from typing import TypeGuard

import numpy as np

from hexcal.estimate.effect_fit import ParamRow

UM = 1e3


def esc(text: object) -> str:
    return html.escape(str(text), quote=True)


def finite(v: float | None) -> TypeGuard[float]:
    return v is not None and bool(np.isfinite(v))


def um(mm: float | None, digits: int = 1) -> str:
    """mm → µm text; an em dash for a missing value."""
    return f"{mm * UM:.{digits}f}" if finite(mm) else "—"


def num(v: float | None, fmt: str = ".3g") -> str:
    return format(v, fmt).replace("-", "−") if finite(v) else "—"


def stat(v: float | None) -> str:
    """A Δχ² or ΔBIC: whole numbers once large (never ``1.389e+04``), 3 digits when small."""
    return num(v, ".0f" if finite(v) and abs(v) >= 100 else ".3g")


def value_ci(p: ParamRow) -> str:
    """``value ± 95 % half-width`` with as many decimals as the interval justifies."""
    if not np.isfinite(p.ci95) or p.ci95 <= 0:
        return num(p.value, ".6g") + " ± —"
    dec = int(np.clip(1 - np.floor(np.log10(p.ci95)), 0, 8))
    return f"{p.value:.{dec}f} ± {p.ci95:.{dec}f}".replace("-", "−")


def data_uri(png: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(png.read_bytes()).decode("ascii")


def figure(fid: str, png: Path | None, title: str, caption: str, skipped: str = "") -> str:
    if png is None:
        return f'<figure id="{fid}" class="skipped"><b>{esc(title)}</b>: {esc(skipped)}</figure>'
    return (
        f'<figure id="{fid}"><img src="{data_uri(png)}" alt="{esc(title)}">'
        f"<figcaption><b>{esc(title)}.</b> {esc(caption)}</figcaption></figure>"
    )


#: Kept on one line: a number and its unit ("22.1 µm", "95 %"), a label and its number
#: ("leg 1", "Model 42"): their space becomes a non-breaking one.
_TOGETHER = re.compile(
    r"(?<=\d) (?=(?:µm|mm|°|%|ppm|s|K|kg|N|×)(?!\w))|(?<=\bleg) (?=\d)|(?<=\bstep) (?=\d)"
    r"|(?<=\bStep) (?=\d)|(?<=\bpose) (?=\d)|(?<=\bModel) (?=\d)"
)
#: A plausible range, "[142.5, 162.5]": one piece.
_RANGE = re.compile(r"\[[−\-]?[\d.]+, [−\-]?[\d.]+\]")
#: An ISO 8601 timestamp: never broken (the page's dd may break anywhere, for hashes).
_TIMESTAMP = re.compile(r"\d{4}-\d\d-\d\dT[\d:.]+(?:[+-]\d\d:\d\d|Z)?")
_TAG = re.compile(r"(<[^>]*>)")
_RAW = re.compile(r"</?(?:title|style|script)\b")
_CELL = re.compile(r"<(t[dh])(\s[^>]*)?>(.*?)</\1>", re.S)
_ROW = re.compile(r"<tr(\s[^>]*)?>(.*?)</tr>", re.S)


def _text_nodes(page: str, fix: Callable[[str], str]) -> str:
    """``fix`` applied to the page's text (not its tags, nor the text of its title, style
    sheet or script, which holds no markup)."""
    out, raw = [], False
    for part in _TAG.split(page):
        if part.startswith("<"):
            if _RAW.match(part):
                raw = not part.startswith("</")
            out.append(part)
        else:
            out.append(part if raw else fix(part))
    return "".join(out)


def _keep_together(text: str) -> str:
    text = _TOGETHER.sub("\u00a0", text)
    text = _RANGE.sub(lambda m: m.group(0).replace(" ", "\u00a0"), text)
    return _TIMESTAMP.sub(lambda m: f'<time class="nowrap">{m.group(0)}</time>', text)


def _labelled(table: str) -> str:
    """A table whose first row is its header, made a ``cards`` table: that row marked ``head``,
    and each later row's
    cells carrying their column's header as ``data-label`` (the page's narrow layout shows
    each row as a card, each value under its label); a cell spanning columns keeps none."""
    rows = _ROW.findall(table)
    if not rows or "<th" not in rows[0][1] or 'class="narrow"' in table[: table.find(">")]:
        return table  # no header, or two columns that fit a phone as they are
    labels = [_TAG.sub("", c[2]).strip() for c in _CELL.findall(rows[0][1])]

    def row(m: re.Match[str]) -> str:
        attrs, body = m.group(1) or "", m.group(2)
        if "<th" in body:
            return f'<tr class="head"{attrs}>{body}</tr>'
        cells = iter(range(len(labels)))

        def cell(c: re.Match[str]) -> str:
            tag, cattrs, inner = c.group(1), c.group(2) or "", c.group(3)
            k = next(cells, None)
            if "colspan" in cattrs or k is None or not labels[k]:
                return f"<{tag}{cattrs}>{inner}</{tag}>"
            label = esc(labels[k])
            return f'<{tag}{cattrs} data-label="{label}"><div class="v">{inner}</div></{tag}>'

        return f"<tr{attrs}>{_CELL.sub(cell, body)}</tr>"

    if table.startswith('<table class="'):  # one class attribute, its classes joined
        marked = table.replace('<table class="', '<table class="cards ', 1)
    else:
        marked = table.replace("<table", '<table class="cards"', 1)
    return _ROW.sub(row, marked)


def for_any_width(page: str) -> str:
    """The finished page made to read at any width (see :mod:`~hexcal.diagnosis.report_style`):
    every table in its own box with its cells labelled by their column (:func:`_labelled`), a
    number never split from its unit nor a label from its number, a timestamp never broken."""
    page = _text_nodes(page, _keep_together)
    page = re.sub(r"<table.*?</table>", lambda m: _labelled(m.group(0)), page, flags=re.S)
    return page.replace("<table", '<div class="tbl"><table').replace("</table>", "</table></div>")
