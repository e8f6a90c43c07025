"""HTML formatting shared by the report's sections (:mod:`hexcal.diagnosis.report`,
:mod:`~hexcal.diagnosis.report_tables`, :mod:`~hexcal.diagnosis.report_pointer`,
:mod:`~hexcal.diagnosis.metrology_html`): every text from the data escaped, numbers in µm with a
true minus sign, an em dash for a missing value, a figure embedded as a ``data:`` URI."""

from __future__ import annotations

import base64
import html
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
