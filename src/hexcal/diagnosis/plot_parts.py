"""The parts every residual figure is drawn from (:mod:`~hexcal.diagnosis.plots`,
:mod:`~hexcal.diagnosis.compare_plots`): a diagnosis seen in plot units (:class:`PlotView`, µm),
the leg colours and the noise-floor band, running medians, the fixed margins that replace
``tight_layout``, the six-panel grid of one scatter per leg, and the axial leg forces.
matplotlib's object API only (:class:`~matplotlib.figure.Figure`, Agg), never pyplot."""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib import rc_context
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from hexcal.effects.compliance import leg_forces

if TYPE_CHECKING:
    from hexcal.diagnosis.diagnose import Diagnosis

#: Resolution of every PNG; sizes are chosen so 9–10 pt text stays legible at it.
DPI = 100
#: mm → µm: residuals are tens of µm, so µm keeps tick labels short.
UM = 1e3
LEG_COLOURS = ("C0", "C1", "C2", "C3", "C4", "C5")
FLOOR_COLOUR = "0.82"


@dataclass(frozen=True)
class PlotView:
    """What every plot of one diagnosis needs, in plot units.

    resid_um (M, 6) µm: held-out residuals (in-sample when the fit was not cross-validated);
    insample_um (M, 6) µm; floor_um (M, 6) µm: noise-floor standard deviation per residual.
    """

    diag: Diagnosis
    model: str
    resid_um: np.ndarray
    resid_label: str
    insample_um: np.ndarray
    floor_um: np.ndarray
    subtitle: str

    @property
    def meas(self):
        return self.diag.problem.meas


#: The colour of a fitted shape drawn over the residual.
LEAD_COLOUR = "#d62728"


def plot_view(diag: Diagnosis) -> PlotView:
    fit = diag.fit
    held = fit.cv_residuals is not None
    resid = fit.cv_residuals if held else fit.residuals
    cv = fit.cv_rms_mm if held else float("nan")
    subtitle = (
        f"RMS {fit.rms_mm * UM:.1f} µm, held-out {cv * UM:.1f} µm, noise floor "
        f"{diag.noise_floor_mm * UM:.1f} µm, χ²/dof {diag.chi2_per_dof:.2f} — verdict: {diag.verdict}"
    )
    return PlotView(
        diag=diag,
        model=fit.model_name,
        resid_um=np.asarray(resid) * UM,
        resid_label="held-out residual (µm)" if held else "residual (µm)",
        insample_um=np.asarray(fit.residuals) * UM,
        floor_um=np.asarray(diag.floor_per_residual) * UM,
        subtitle=subtitle,
    )


def figure_style() -> AbstractContextManager:
    """The settings every figure is drawn with, for the figures made in this context. Titles
    sit at their axes' top, where matplotlib's automatic placement puts them anyway (no figure
    has ticks or labels above its panels): that spares it from measuring every tick label to
    decide so, a fifth of a figure's drawing time. The PNGs are byte for byte the same."""
    return rc_context({"axes.titley": 1.0})


def _window(n: int) -> int:
    """Points in a running window: a fifth of the data (a median of fewer points wanders with the
    noise and hides a trend), at least 7, never more than the data."""
    return min(n, max(7, n // 5))


def running(
    x: np.ndarray, y: np.ndarray, stat: Callable = np.nanmedian
) -> tuple[np.ndarray, np.ndarray]:
    """Running ``stat`` (a NaN-ignoring reducer taking ``axis``) of ``y`` over ``x``: (sorted x,
    value at each), each (n,). The window is centred and shrinks at the ends, so the line spans
    the whole range of ``x``; empty when there are fewer than 5 finite points."""
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    n = len(x)
    if n < 5:
        return np.empty(0), np.empty(0)
    order = np.argsort(x, kind="stable")
    h = _window(n) // 2
    # NaN padding shrinks the window at the ends without a Python loop over the points.
    padded = np.concatenate([np.full(h, np.nan), y[order], np.full(h, np.nan)])
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * h + 1)
    return x[order], stat(windows, axis=1)


def floor_band(ax: Axes, x: np.ndarray, floor: np.ndarray) -> None:
    """±2σ noise-floor band along ``x``; the per-pose floor is smoothed (running median) so the
    band's edge shows the trend, not pose-to-pose jitter."""
    xs, fs = running(x, floor)
    if len(xs) == 0:
        return
    ax.fill_between(xs, -2 * fs, 2 * fs, color=FLOOR_COLOUR, lw=0, zorder=0)


#: The margins of every plot, inches: room for the y label and its ticks on the left, the
#: two-line title on top, the x label and its ticks below; between panels, room for a title and
#: an x label across rows, and for the tick labels across columns unless the panels share y.
#: Fixed, rather than ``tight_layout``, which measured every tick label of every panel twice
#: (2.4 s of a 7 s report).
MARGIN_IN = {"left": 0.85, "right": 0.25, "top": 0.8, "bottom": 0.6}
GAP_IN = {"rows": 0.95, "cols": 0.95, "shared_cols": 0.3}


def fixed_layout(fig: Figure, legend_in: float = 0.0) -> None:
    """Place ``fig``'s grid of panels by :data:`MARGIN_IN` and :data:`GAP_IN`, leaving
    ``legend_in`` inches along the bottom for a legend."""
    w, h = fig.get_figwidth(), fig.get_figheight()
    axes = [ax for ax in fig.axes if ax.get_subplotspec() is not None]
    if not axes:
        return
    grid = axes[0].get_subplotspec().get_gridspec()  # type: ignore[union-attr]
    rows, cols = grid.nrows, grid.ncols
    shared = len(axes) > 1 and axes[0].get_shared_y_axes().joined(axes[0], axes[1])
    gap_w = GAP_IN["shared_cols"] if shared else GAP_IN["cols"]
    left, right = MARGIN_IN["left"], w - MARGIN_IN["right"]
    bottom, top = MARGIN_IN["bottom"] + legend_in, h - MARGIN_IN["top"]
    # wspace and hspace are fractions of the mean panel's width and height.
    panel_w = (right - left - (cols - 1) * gap_w) / cols
    panel_h = (top - bottom - (rows - 1) * GAP_IN["rows"]) / rows
    fig.subplots_adjust(
        left=left / w,
        right=right / w,
        bottom=bottom / h,
        top=top / h,
        wspace=gap_w / panel_w,
        hspace=GAP_IN["rows"] / panel_h,
    )


def finish(fig: Figure, outdir: Path, name: str, legend: list | None = None) -> Path:
    """Legend along the bottom, the fixed layout, PNG at :data:`DPI`."""
    legend_in = 0.0
    if legend:
        fig.legend(handles=legend, loc="lower center", ncol=len(legend), fontsize=9, frameon=False)
        legend_in = 0.35  # one row of 9 pt legend text
    fixed_layout(fig, legend_in)
    path = outdir / name
    # Not fig.clear(): that resets every axes' ticks before dropping them, a fifth of the
    # figure's time; the garbage collector frees the figure (a few MB) soon enough.
    fig.savefig(path, dpi=DPI, format="png")  # the suffix may be a temporary file's
    return path


def figure_title(fig: Figure, view: PlotView, what: str) -> None:
    fig.suptitle(f"{view.model} — {what}\n{view.subtitle}", fontsize=11)


def legend_handles(view: PlotView, line: str = "running median") -> list:
    return [
        Line2D(
            [],
            [],
            ls="",
            marker="o",
            ms=4,
            color="0.3",
            alpha=0.6,
            label=view.resid_label.split(" (")[0],
        ),
        Patch(color=FLOOR_COLOUR, label="±2σ noise floor"),
        Line2D([], [], color="k", lw=1.6, label=line),
    ]


def leg_grid(figsize: tuple[float, float] = (11, 6.6)) -> tuple[Figure, np.ndarray]:
    fig = Figure(figsize=figsize)
    axes = fig.subplots(2, 3, sharey=True, squeeze=False)
    return fig, axes.ravel()


def leg_scatter(
    view: PlotView,
    x: np.ndarray,
    xlabel: str,
    what: str,
    outdir: Path,
    name: str,
    note: str = "",
    curve: np.ndarray | None = None,
) -> Path:
    """Six panels, one per leg: held-out residual against ``x`` (M, 6), floor band, running
    median; and ``curve`` (M, 6) µm, what a fitted shape takes out of it, drawn over it (its
    running median) where given."""
    fig, axes = leg_grid()
    for k, ax in enumerate(axes):
        xk, rk = x[:, k], view.resid_um[:, k]
        floor_band(ax, xk, view.floor_um[:, k])
        ax.axhline(0, color="0.5", lw=0.6)
        ax.plot(xk, rk, "o", ms=3, color=LEG_COLOURS[k], alpha=0.55, mec="none")
        xs, ms = running(xk, rk)
        ax.plot(xs, ms, "-", color="k", lw=1.6)
        if curve is not None and np.ptp(curve[:, k]) > 0:
            # What the lead takes out of the residual is no function of x alone (the geometry
            # refitted with it takes up its part pose by pose): its running median, as the
            # residual's, so that the two lines meet where the lead explains.
            xc, mc = running(xk, curve[:, k])
            ax.plot(xc, mc, "-", color=LEAD_COLOUR, lw=1.8)
        ax.set_title(f"leg {k + 1}", fontsize=10)
        ax.set_xlabel(xlabel)
        ax.grid(True, alpha=0.25)
        if k % 3 == 0:
            ax.set_ylabel(view.resid_label)
    figure_title(fig, view, what + (f" ({note})" if note else ""))
    legend = legend_handles(view)
    if curve is not None:
        legend.append(
            Line2D([], [], color=LEAD_COLOUR, lw=1.8, label="what the lead takes out (median)")
        )
    return finish(fig, outdir, name, legend)


def _mass(design) -> tuple[float, str]:
    """Platform mass (kg) for the leg forces and the label saying where it came from."""
    if design.platform_mass_kg:
        return float(
            design.platform_mass_kg
        ), f"platform mass {design.platform_mass_kg:g} kg from robot.json"
    return 1.0, "platform mass unknown: 1 kg ASSUMED, forces are relative"


def axial_forces(diag: Diagnosis) -> tuple[np.ndarray, str]:
    """(M, 6) N axial leg forces (compression positive) with the label of the mass used — the
    same forces the compliance effect uses, centre of mass included when robot.json has one."""
    design = diag.problem.design
    mass, label = _mass(design)
    com = getattr(design, "platform_com_mm", None)
    return leg_forces(
        diag.problem.data, mass, None if com is None else np.asarray(com, float)
    ), label
