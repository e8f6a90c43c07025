"""Residual plots of a :class:`~hexcal.diagnosis.diagnose.Diagnosis`: where the model fails.

Each plot sets the residual (reading − predicted, shown in µm) against the quantity one
catalogue effect depends on, so a missing effect shows as structure beside the ±2σ noise-floor
band: a slope against the reading (gain), a step between motion directions (backlash), a trend
with temperature (thermal) or axial force (compliance), a periodic ripple in the reading
(lead screw), a constant per leg (offset).

The scatter plots show the *held-out* residuals (random 5-fold cross-validation, each pose
predicted by a fit that did not see it) because an in-sample residual is partly absorbed by the
geometry; the normalised histogram uses the in-sample residual, which is what the noise floor
describes. The figures use matplotlib's object API (:class:`matplotlib.figure.Figure`, Agg
canvas) and never pyplot, so writing plots neither switches a caller's backend nor registers
figures in pyplot's global list: a figure is freed as soon as it goes out of scope.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.artist import Artist
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import NullFormatter

from hexcal.diagnosis.figure_pool import FigureJob, draw_all
from hexcal.diagnosis.periodogram import (
    FALSE_ALARM,
    PERIOD_RANGE_MM,
    period_grid,
    periodogram_and_level,
)
from hexcal.diagnosis.plot_parts import (
    FLOOR_COLOUR,
    LEG_COLOURS,
    UM,
    PlotView,
    axial_forces,
    figure_style,
    figure_title,
    finish,
    floor_band,
    leg_grid,
    leg_scatter,
    legend_handles,
    plot_view,
    running,
)
from hexcal.effects.backlash import deadband_mm, motion_state
from hexcal.estimate.quantiles import norm_pdf, norm_ppf

if TYPE_CHECKING:
    from hexcal.diagnosis.diagnose import Diagnosis

MOTION_LABELS = {-1: "retracting\n(−1)", 0: "not yet\nmoved (0)", 1: "extending\n(+1)"}

#: File names written by :func:`write_plots`, in the order returned.
PLOT_NAMES = (
    "residuals_vs_reading.png",
    "residuals_vs_motion.png",
    "residuals_vs_force.png",
    "residuals_vs_temperature.png",
    "residuals_vs_time.png",
    "residuals_vs_pose.png",
    "residuals_vs_direction.png",
    "periodogram.png",
    "predicted_vs_measured.png",
    "per_leg_rms.png",
    "residuals_vs_covariate.png",
)


# --- the plots ---------------------------------------------------------------------------------


def _plot_reading(view: PlotView, outdir: Path, name: str) -> Path:
    return leg_scatter(
        view,
        view.meas.readings,
        "encoder reading (mm)",
        "residual against leg reading",
        outdir,
        name,
    )


def _plot_motion(view: PlotView, outdir: Path, name: str) -> Path:
    """Residual by the direction each leg last moved: backlash is a step between −1 and +1."""
    state = motion_state(view.meas.readings, deadband_mm(view.diag.problem.data))
    fig, axes = leg_grid()
    rng = np.random.default_rng(0)  # fixed jitter: the same data give the same picture
    for k, ax in enumerate(axes):
        ax.axhline(0, color="0.5", lw=0.6)
        groups, positions = [], []
        for s in (-1, 0, 1):
            sel = state[:, k] == s
            if not sel.any():
                continue
            r = view.resid_um[sel, k]
            fl = float(np.sqrt(np.mean(view.floor_um[sel, k] ** 2)))
            ax.fill_between([s - 0.4, s + 0.4], -2 * fl, 2 * fl, color=FLOOR_COLOUR, lw=0, zorder=0)
            ax.plot(
                s + rng.uniform(-0.18, 0.18, sel.sum()),
                r,
                "o",
                ms=3,
                color=LEG_COLOURS[k],
                alpha=0.5,
                mec="none",
            )
            groups.append(r)
            positions.append(s)
        if groups:
            ax.boxplot(
                groups,
                positions=positions,
                widths=0.5,
                showfliers=False,
                manage_ticks=False,
                medianprops={"color": "k", "lw": 1.6},
                boxprops={"lw": 0.9},
                whiskerprops={"lw": 0.9},
            )
        ax.set_xticks([-1, 0, 1], [MOTION_LABELS[s] for s in (-1, 0, 1)], fontsize=8.5)
        ax.set_xlim(-1.6, 1.6)
        title = f"leg {k + 1}"
        ext, ret = view.resid_um[state[:, k] > 0, k], view.resid_um[state[:, k] < 0, k]
        if len(ext) and len(ret):
            # The step between medians reads directly as the backlash (the model's β).
            title += f": median(+1) − median(−1) = {np.median(ext) - np.median(ret):+.1f} µm"
        ax.set_title(title, fontsize=9.5)
        ax.grid(True, axis="y", alpha=0.25)
        if k % 3 == 0:
            ax.set_ylabel(view.resid_label)
        if k >= 3:
            ax.set_xlabel("direction of the leg's last motion")
    figure_title(fig, view, "residual by direction of last motion (backlash shows as a step)")
    return finish(
        fig,
        outdir,
        name,
        legend_handles(view, "box: quartiles and median"),
    )


def _plot_force(view: PlotView, outdir: Path, name: str) -> Path:
    f, label = axial_forces(view.diag)
    return leg_scatter(
        view,
        f,
        "axial leg force, compression + (N)",
        "residual against leg force",
        outdir,
        name,
        note=label,
    )


def _plot_temperature(view: PlotView, outdir: Path, name: str) -> Path:
    temp = np.repeat(view.meas.temperature[:, None], 6, axis=1)
    return leg_scatter(
        view, temp, "structure temperature (°C)", "residual against temperature", outdir, name
    )


def _time_axis(t: np.ndarray) -> tuple[np.ndarray, str]:
    if np.ptp(t) > 600:
        return t / 60.0, "time since session start (min)"
    return t, "time since session start (s)"


def _plot_time(view: PlotView, outdir: Path, name: str) -> Path:
    """All legs against time, running mean per leg; the five time blocks of the ``where``
    analysis are marked so a drift can be matched with its summary line."""
    meas = view.meas
    t, xlabel = _time_axis(np.asarray(meas.t, float))
    fig = Figure(figsize=(11, 5.2))
    ax = fig.subplots()
    floor = np.sqrt(np.mean(view.floor_um**2, axis=1))
    floor_band(ax, t, floor)
    ax.axhline(0, color="0.5", lw=0.6)
    for k in range(6):
        ax.plot(t, view.resid_um[:, k], "o", ms=2.5, color=LEG_COLOURS[k], alpha=0.45, mec="none")
        xs, ms = running(t, view.resid_um[:, k], np.nanmean)
        ax.plot(xs, ms, "-", color=LEG_COLOURS[k], lw=1.8)
    blocks = np.array_split(np.arange(len(t)), 5)
    for i, b in enumerate(blocks):
        if len(b) == 0:
            continue
        if i:
            ax.axvline(t[b[0]], color="0.55", lw=0.8, ls=":")
        ax.annotate(
            f"block {i + 1}/5",
            (t[b[len(b) // 2]], 1.0),
            xycoords=("data", "axes fraction"),
            ha="center",
            va="top",
            fontsize=8,
            color="0.4",
        )
    ax.set_xlabel(xlabel)
    ax.set_ylabel(view.resid_label)
    ax.grid(True, alpha=0.25)
    figure_title(fig, view, "residual against time (recording order)")
    legend: list[Artist] = [
        Line2D([], [], color=LEG_COLOURS[k], marker="o", ms=4, lw=1.8, label=f"leg {k + 1}")
        for k in range(6)
    ]
    legend += [
        Patch(color=FLOOR_COLOUR, label="±2σ floor"),
        Line2D([], [], color="0.4", lw=1.8, label="running mean"),
    ]
    return finish(fig, outdir, name, legend)


def _plot_pose(view: PlotView, outdir: Path, name: str) -> Path:
    meas = view.meas
    tilt = np.degrees(meas.rotations.magnitude())
    cols = [
        (meas.position[:, 0], "platform x (mm)"),
        (meas.position[:, 1], "platform y (mm)"),
        (meas.position[:, 2], "platform z (mm)"),
        (tilt, "tilt |rotation vector| (deg)"),
    ]
    fig = Figure(figsize=(11, 4.6))
    axes = fig.subplots(1, 4, sharey=True)
    floor = np.sqrt(np.mean(view.floor_um**2, axis=1))
    for i, (ax, (x, xlabel)) in enumerate(zip(axes, cols, strict=True)):
        floor_band(ax, x, floor)
        ax.axhline(0, color="0.5", lw=0.6)
        for k in range(6):
            ax.plot(
                x, view.resid_um[:, k], "o", ms=2.2, color=LEG_COLOURS[k], alpha=0.4, mec="none"
            )
            xs, ms = running(x, view.resid_um[:, k])
            ax.plot(xs, ms, "-", color=LEG_COLOURS[k], lw=1.3)
        ax.set_xlabel(xlabel)
        ax.grid(True, alpha=0.25)
        if i == 0:
            ax.set_ylabel(view.resid_label)
    figure_title(fig, view, "residual against platform pose")
    legend: list[Artist] = [
        Line2D([], [], color=LEG_COLOURS[k], marker="o", ms=4, lw=1.3, label=f"leg {k + 1}")
        for k in range(6)
    ]
    legend += [
        Patch(color=FLOOR_COLOUR, label="±2σ floor"),
        Line2D([], [], color="0.4", lw=1.3, label="running median"),
    ]
    return finish(fig, outdir, name, legend)


def leg_direction_angles(diag: Diagnosis) -> np.ndarray:
    """(M, 6) deg: angle of each leg's unit vector from that leg's mean direction over the
    session, at the fitted geometry."""
    ref = diag.fit.refinement
    meas = diag.problem.meas
    v = meas.position[:, None, :] + np.einsum("mij,kj->mki", diag.problem.R, ref.b) - ref.a[None]
    u = v / np.linalg.norm(v, axis=-1, keepdims=True)
    mean = u.mean(axis=0)
    mean /= np.linalg.norm(mean, axis=-1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.einsum("mki,ki->mk", u, mean), -1.0, 1.0)))


def _plot_direction(view: PlotView, outdir: Path, name: str) -> Path:
    ang = leg_direction_angles(view.diag)
    return leg_scatter(
        view,
        ang,
        "angle from the leg's mean direction (deg)",
        "residual against leg direction",
        outdir,
        name,
    )


def _plot_periodogram(view: PlotView, outdir: Path, name: str) -> Path:
    """Per leg, the amplitude of a periodic residual against the reading, with the level white
    noise at the floor reaches with probability :data:`FALSE_ALARM` anywhere in the band."""
    meas = view.meas
    pitch = view.diag.problem.design.leadscrew_pitch_mm
    fig, axes = leg_grid()
    top = 0.0
    for k, ax in enumerate(axes):
        x, r = meas.readings[:, k], view.resid_um[:, k]
        span = float(np.ptp(x))
        ax.set_title(f"leg {k + 1} (reading span {span:.1f} mm)", fontsize=10)
        ax.set_xscale("log")
        ax.set_xlim(*PERIOD_RANGE_MM)
        # Plain numbers: "10⁰" tick labels make a reader convert before reading a period.
        ax.set_xticks([0.5, 1, 2, 5, 10, 20], ["0.5", "1", "2", "5", "10", "20"])
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("period in the reading (mm)")
        if k % 3 == 0:
            ax.set_ylabel("amplitude (µm)")
        ax.grid(True, which="both", alpha=0.25)
        if pitch:
            ax.axvline(pitch, color="C3", lw=1.2, ls="--")
        if span < PERIOD_RANGE_MM[0] or len(x) < 8:
            # A leg that hardly moved carries no periodic information: say so, do not fail.
            ax.text(
                0.5,
                0.5,
                "reading range too small\nfor a periodogram",
                transform=ax.transAxes,
                ha="center",
                va="center",
                color="0.4",
            )
            continue
        periods = period_grid(span)
        sigma = float(np.sqrt(np.mean(view.floor_um[:, k] ** 2)))
        amp, level = periodogram_and_level(x, r, periods, sigma)
        ax.plot(periods, amp, color=LEG_COLOURS[k], lw=1.0)
        # The noise level at its highest over each resolution element (5 grid points): its
        # jitter from one frequency to the next is the readings' spacing, not information.
        pad = np.concatenate([np.full(2, np.nan), level, np.full(2, np.nan)])
        level = np.fmax.reduce(np.lib.stride_tricks.sliding_window_view(pad, 5), axis=1)
        ax.plot(periods, level, color="0.35", lw=1.0, ls=":")
        # The level's typical height, not its peaks where the readings resolve no period.
        top = max(top, float(np.nanmedian(level)), float(np.nanmax(amp)))
    # The panels share y: one scale for all legs, so the largest ripple sets it.
    axes[0].set_ylim(0, top * 1.1 if top > 0 else 1.0)
    pitch_note = (
        f"lead-screw pitch {pitch:g} mm"
        if pitch
        else "lead-screw pitch unknown (not in robot.json)"
    )
    figure_title(fig, view, f"periodogram of the residual against the reading ({pitch_note})")
    legend = [
        Line2D([], [], color="0.3", lw=1.0, label="Lomb–Scargle amplitude"),
        Line2D(
            [],
            [],
            color="0.35",
            lw=1.0,
            ls=":",
            label=f"noise level ({100 * (1 - FALSE_ALARM):.0f} %)",
        ),
    ]
    if pitch:
        legend.append(Line2D([], [], color="C3", lw=1.2, ls="--", label=f"pitch {pitch:g} mm"))
    return finish(fig, outdir, name, legend)


def _plot_normalised(view: PlotView, outdir: Path, name: str) -> Path:
    """Histogram of r / floor against N(0, 1) and a normal Q–Q plot: at the floor the
    histogram follows the curve and the Q–Q points the diagonal."""
    z_in = (view.insample_um / view.floor_um).ravel()
    z_cv = (view.resid_um / view.floor_um).ravel()
    fig = Figure(figsize=(11, 4.6))
    ax, qq = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.5, 1]})
    lim = max(4.0, float(np.nanpercentile(np.abs(z_cv), 99.5)) * 1.05)
    bins = np.linspace(-lim, lim, 61)
    ax.hist(
        np.clip(z_in, -lim, lim),
        bins=bins,
        density=True,
        color="C0",
        alpha=0.55,
        label=f"in-sample (SD {np.std(z_in):.2f})",
    )
    ax.hist(
        np.clip(z_cv, -lim, lim),
        bins=bins,
        density=True,
        histtype="step",
        color="C1",
        lw=1.4,
        label=f"held-out (SD {np.std(z_cv):.2f})",
    )
    g = np.linspace(-lim, lim, 400)
    ax.plot(g, norm_pdf(g), "k-", lw=1.6, label="N(0, 1): noise only")
    ax.set_xlabel("normalised residual r / σ_floor (1)")
    ax.set_ylabel("probability density (1/σ)")
    ax.set_title(
        "histogram of normalised residuals (outliers clipped to the edge bins)", fontsize=10
    )
    ax.legend(fontsize=9)
    ax.grid(True, alpha=0.25)
    zs = np.sort(z_in)
    q = norm_ppf((np.arange(1, len(zs) + 1) - 0.5) / len(zs))
    qq.plot(q, zs, "o", ms=2.5, color="C0", alpha=0.5, mec="none")
    qq.plot(q, q, "k-", lw=1.2)
    qq.set_xlabel("N(0, 1) quantile (1)")
    qq.set_ylabel("in-sample r / σ_floor, sorted (1)")
    qq.set_title("normal Q–Q plot: on the line at the floor", fontsize=10)
    qq.grid(True, alpha=0.25)
    figure_title(fig, view, "residual relative to the noise floor")
    return finish(fig, outdir, name)


def _plot_per_leg_rms(view: PlotView, outdir: Path, name: str) -> Path:
    fit = view.diag.fit
    legs = np.arange(1, 7)
    floor = np.sqrt(np.mean(view.floor_um**2, axis=0))
    held = fit.cv_rms_per_leg * UM if fit.cv_residuals is not None else np.full(6, np.nan)
    fig = Figure(figsize=(9, 4.8))
    ax = fig.subplots()
    w = 0.27
    ax.bar(legs - w, fit.rms_per_leg * UM, w, color="C0", label="in-sample RMS")
    ax.bar(legs, held, w, color="C1", label="held-out RMS")
    ax.bar(legs + w, floor, w, color=FLOOR_COLOUR, edgecolor="0.5", label="noise floor of the leg")
    ax.axhline(view.diag.noise_floor_mm * UM, color="0.3", lw=1.0, ls="--", label="overall floor")
    handles, labels = ax.get_legend_handles_labels()
    # Bars first, in the order drawn, then the line: the legend reads like the bar groups.
    order = [
        labels.index(lab)
        for lab in ("in-sample RMS", "held-out RMS", "noise floor of the leg", "overall floor")
    ]
    ax.set_xticks(legs, [f"leg {k}" for k in legs])
    ax.set_ylim(0, ax.get_ylim()[1] * 1.08)  # head room: the bars should not touch the frame
    ax.set_ylabel("RMS (µm)")
    ax.grid(True, axis="y", alpha=0.25)
    figure_title(fig, view, "RMS residual per leg")
    return finish(fig, outdir, name, [handles[i] for i in order])


def _plot_covariate(view: PlotView, outdir: Path, name: str) -> Path:
    """The residual against the covariate an unexplained residual follows (the covariate
    explorer's lead), on the legs that carry its shape."""
    x = view.diag.exploration
    lead = None if x is None else x.lead
    if lead is None:
        raise ValueError("no covariate leads: nothing to plot against")
    cov = lead.covariate
    legs = lead.shape.legs
    on = "" if len(legs) == 6 else f" on leg{'s' * (len(legs) > 1)} {', '.join(map(str, legs))}"
    along, xlabel, _ = lead.axis()
    return leg_scatter(
        view,
        along,
        xlabel,
        f"residual against the {cov.name.replace('_', ' ')}",
        outdir,
        name,
        note=f"{100 * lead.share:.0f} % of the excess: {lead.shape.describe(lead.covariate.unit)}{on}",
        curve=lead.seen_um(),
    )


_PLOTS: dict[str, Callable[[PlotView, Path, str], Path]] = {
    "residuals_vs_reading.png": _plot_reading,
    "residuals_vs_motion.png": _plot_motion,
    "residuals_vs_force.png": _plot_force,
    "residuals_vs_temperature.png": _plot_temperature,
    "residuals_vs_time.png": _plot_time,
    "residuals_vs_pose.png": _plot_pose,
    "residuals_vs_direction.png": _plot_direction,
    "periodogram.png": _plot_periodogram,
    "predicted_vs_measured.png": _plot_normalised,
    "per_leg_rms.png": _plot_per_leg_rms,
    "residuals_vs_covariate.png": _plot_covariate,
}


def plot_names(diag: Diagnosis, only: Iterable[str] | None = None) -> list[str]:
    """The plots :func:`write_plots` draws for ``diag``, in :data:`PLOT_NAMES`' order: ``only``
    (all by default) less the temperature plot when the measurements have no temperature and
    the covariate plot when no covariate leads."""
    wanted = set(PLOT_NAMES if only is None else only)
    unknown = wanted - set(PLOT_NAMES)
    if unknown:
        raise ValueError(
            f"unknown plot(s) {sorted(unknown)}; the plots are: {', '.join(PLOT_NAMES)}"
        )
    return [
        name
        for name in _PLOTS
        if name in wanted
        and not (name == "residuals_vs_temperature.png" and diag.problem.meas.temperature is None)
        and not (name == "residuals_vs_covariate.png" and _no_lead(diag))
    ]


#: Drawing cost of a plot against a six-panel scatter (1, about 0.2 s), measured on a two-step
#: report: the costliest are drawn first, so that the two processes drawing them in turns end
#: on a cheap one (:mod:`~hexcal.diagnosis.figure_pool`). Only the order depends on them.
_WEIGHTS = {
    "periodogram.png": 1.6,  # its spectra and log axes
    "residuals_vs_motion.png": 1.25,
    "residuals_vs_time.png": 0.5,
    "residuals_vs_pose.png": 0.85,
    "per_leg_rms.png": 0.35,
    "predicted_vs_measured.png": 0.65,
}


def plot_jobs(
    diag: Diagnosis, outdir: Path, prefix: str = "", only: Iterable[str] | None = None
) -> list[FigureJob]:
    """The residual plots of ``diag`` (:func:`plot_names`) as figures to draw into ``outdir``
    (created), each named ``prefix`` + its name."""
    names = plot_names(diag, only)
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    view = plot_view(diag)

    def job(name: str) -> FigureJob:
        def draw(path: Path) -> Path:
            with figure_style():
                return _PLOTS[name](view, path.parent, path.name)

        return FigureJob(outdir / (prefix + name), draw, _WEIGHTS.get(name, 1.0))

    return [job(name) for name in names]


def write_plots(
    diag: Diagnosis,
    outdir: Path,
    prefix: str = "",
    only: Iterable[str] | None = None,
    on_plot: Callable[[str], None] | None = None,
) -> list[Path]:
    """Write the residual plots of ``diag``'s current fit as PNGs into ``outdir`` (created if
    needed), each named ``prefix`` + one of :data:`PLOT_NAMES`; return the paths written, in
    that order. ``only``: a subset of :data:`PLOT_NAMES` to write (all by default).

    ``residuals_vs_covariate.png`` (the residual against the covariate an unexplained residual
    follows) is written only when one leads.
    ``residuals_vs_temperature.png`` is skipped when the measurements have no temperature; the
    periodogram is drawn without the pitch marker when robot.json has no lead-screw pitch.
    ``on_plot`` is called with each plot's name once it is drawn (a progress bar). The plots are
    shared with a forked copy of this process where that pays (:mod:`hexcal.diagnosis.figure_pool`).
    """
    done = None if on_plot is None else (lambda path: on_plot(path.name.removeprefix(prefix)))
    return draw_all(plot_jobs(diag, outdir, prefix, only), done)


def _no_lead(diag: Diagnosis) -> bool:
    x = getattr(diag, "exploration", None)
    return x is None or x.lead is None
