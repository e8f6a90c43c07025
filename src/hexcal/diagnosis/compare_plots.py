"""Comparison plots of a diagnosis sequence: the residual before and after an effect was added
(against the quantity the effect depends on), and the pose error over the workspace for the
drawing and each model. The per-step residual plots and their helpers are
:mod:`hexcal.diagnosis.plots`."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from hexcal.diagnosis.figure_pool import FigureJob
from hexcal.diagnosis.plot_parts import (
    DPI,
    LEG_COLOURS,
    UM,
    axial_forces,
    figure_style,
    finish,
    plot_view,
    running,
)
from hexcal.effects.backlash import deadband_mm, motion_state

if TYPE_CHECKING:
    from hexcal.diagnosis.diagnose import Diagnosis


# --- before / after ----------------------------------------------------------------------------


def _added(before: Diagnosis, after: Diagnosis) -> list[str]:
    return [e for e in after.effects if e not in before.effects]


def _betraying_panel(ax: Axes, diag: Diagnosis, effect: str) -> None:
    """Residual of ``diag`` against the quantity ``effect`` depends on, all legs on one axis."""
    view = plot_view(diag)
    meas = view.meas
    r = view.resid_um
    rng = np.random.default_rng(0)
    ax.axhline(0, color="0.5", lw=0.6)
    if effect in ("backlash", "offset"):
        # Categorical: per leg, one strip per motion state (backlash) or one strip (offset).
        if effect == "backlash":
            state = motion_state(meas.readings, deadband_mm(diag.problem.data))
            shifts = {-1: -0.27, 0: 0.0, 1: 0.27}
            markers = {-1: "v", 0: "o", 1: "^"}
        else:
            state = np.zeros_like(r)
            shifts, markers = {0: 0.0}, {0: "o"}
        for k in range(6):
            for s, dx in shifts.items():
                sel = state[:, k] == s
                if not sel.any():
                    continue
                x = k + 1 + dx + rng.uniform(-0.09, 0.09, sel.sum())
                ax.plot(x, r[sel, k], markers[s], ms=3, color=LEG_COLOURS[k], alpha=0.5, mec="none")
                ax.plot(
                    [k + 1 + dx - 0.11, k + 1 + dx + 0.11], [np.median(r[sel, k])] * 2, "k-", lw=1.8
                )
        ax.set_xticks(range(1, 7), [f"leg {k}" for k in range(1, 7)])
        if effect == "backlash":
            ax.set_xlabel("leg; ▼ retracting, ● not yet moved, ▲ extending (bar: median)")
        else:
            ax.set_xlabel("leg (bar: median)")
        return
    if effect == "thermal" and meas.temperature is not None:
        x = np.repeat(meas.temperature[:, None], 6, axis=1)
        xlabel = "structure temperature (°C)"
    elif effect == "compliance":
        x, label = axial_forces(diag)
        xlabel = f"axial leg force (N; {label})"
    elif effect == "leadscrew" and diag.problem.design.leadscrew_pitch_mm:
        # Folding the reading by the pitch lines up every turn, so the ripple is one curve.
        pitch = float(diag.problem.design.leadscrew_pitch_mm)
        x = np.mod(meas.readings, pitch)
        xlabel = f"reading modulo the lead-screw pitch {pitch:g} mm (mm)"
    else:
        x = meas.readings
        xlabel = "encoder reading (mm)"
    for k in range(6):
        ax.plot(x[:, k], r[:, k], "o", ms=2.5, color=LEG_COLOURS[k], alpha=0.45, mec="none")
        xs, ms = running(x[:, k], r[:, k])
        ax.plot(xs, ms, "-", color=LEG_COLOURS[k], lw=1.5)
    ax.set_xlabel(xlabel)


def before_after(
    before: Diagnosis, after: Diagnosis, outdir: Path, name: str = "before_after.png"
) -> Path:
    """Side by side, before and after adding effect(s): per-leg held-out RMS against the noise
    floor, and the residual against the quantity that betrays the added effect (the first one
    added when several are). Returns the PNG path."""
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    added = _added(before, after)
    effect = added[0] if added else "gain"  # no effect added: the reading is the generic axis
    with figure_style():
        fig = Figure(figsize=(11, 8.4))
        axes = fig.subplots(2, 2)
    legs = np.arange(1, 7)
    top = 0.0
    for ax, d, tag in ((axes[0, 0], before, "before"), (axes[0, 1], after, "after")):
        fit = d.fit
        held = fit.cv_rms_per_leg * UM if fit.cv_residuals is not None else fit.rms_per_leg * UM
        floor = np.sqrt(np.mean((d.floor_per_residual * UM) ** 2, axis=0))
        ax.bar(legs, held, 0.6, color=LEG_COLOURS, alpha=0.85)
        ax.plot(legs, floor, "_", color="k", ms=26, mew=2)
        ax.axhline(d.noise_floor_mm * UM, color="0.5", ls="--", lw=1.0)
        ax.set_xticks(legs, [f"leg {k}" for k in legs])
        ax.set_ylabel("held-out RMS (µm)")
        ax.set_title(
            f"{tag}: {fit.model_name}\nheld-out RMS {fit.cv_rms_mm * UM:.1f} µm "
            f"({'estimated floor' if d.floor_estimated else 'floor'} "
            f"{d.noise_floor_mm * UM:.1f} µm) — verdict {d.verdict}",
            fontsize=10,
        )
        ax.grid(True, axis="y", alpha=0.25)
        top = max(top, float(np.nanmax(held)), float(floor.max()))
    for ax in axes[0]:
        ax.set_ylim(0, top * 1.15)  # one scale, so the drop is visible at a glance
    for ax, d, tag in ((axes[1, 0], before, "before"), (axes[1, 1], after, "after")):
        _betraying_panel(ax, d, effect)
        ax.set_ylabel("held-out residual (µm)")
        ax.set_title(f"{tag}: residual against what betrays {effect}", fontsize=10)
        ax.grid(True, alpha=0.25)
    lo = min(a.get_ylim()[0] for a in axes[1])
    hi = max(a.get_ylim()[1] for a in axes[1])
    for ax in axes[1]:
        ax.set_ylim(lo, hi)
    what = " + ".join(added) if added else "no effect"
    fig.suptitle(f"{before.fit.model_name} → {after.fit.model_name}: adding {what}", fontsize=11)
    legend = [
        Line2D([], [], ls="", marker="_", ms=16, mew=2, color="k", label="noise floor of the leg"),
        Line2D([], [], ls="--", color="0.5", label="overall noise floor"),
        Line2D([], [], ls="", marker="o", ms=4, color="0.4", label="held-out residual"),
        Line2D(
            [],
            [],
            color="k",
            lw=1.6,
            label="median" if effect in ("backlash", "offset") else "running median (per leg)",
        ),
    ]
    return finish(fig, outdir, name, legend)


# --- pose error over the workspace ---------------------------------------------------------------


def pose_error_map(diags: list[Diagnosis], outdir: Path, name: str = "pose_error.png") -> Path:
    """The pose error over the workspace, before and after: the platform positions seen from
    above (x, y), coloured by the position error of the pose each model computes from the
    readings (µm, one log scale for all panels), for the drawing, the first model and the last
    (held-out). Returns the PNG path."""
    from matplotlib.colors import LogNorm

    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    first, last = diags[0], diags[-1]
    # Each step's errors are over the poses it kept (gross outliers set aside), so each panel
    # places its own poses.
    shown = [
        ("drawing (robot.json)", first.design_pose_errors, "all poses", first.problem.meas),
        (first.fit.model_name, first.pose_errors, "held-out", first.problem.meas),
    ]
    if len(diags) > 1:
        shown.append((last.fit.model_name, last.pose_errors, "held-out", last.problem.meas))
    panels = [(title, e, kind) for title, e, kind, _ in shown if e is not None]
    where = [meas for _, e, _, meas in shown if e is not None]
    values = np.concatenate([e.position_mm[e.closed] for _, e, _ in panels]) * UM
    lo = max(float(np.min(values[values > 0])), 1e-3)
    norm_ = LogNorm(vmin=lo, vmax=max(float(values.max()), 10 * lo))
    with figure_style():
        fig = Figure(figsize=(4.0 * len(panels) + 1.0, 4.8), layout="constrained")
        axes = fig.subplots(1, len(panels), squeeze=False)[0]
    art = None
    for ax, (title, e, kind), meas in zip(axes, panels, where, strict=True):
        x, y = meas.position[:, 0], meas.position[:, 1]
        err = np.where(e.closed, e.position_mm, np.nan) * UM
        order = np.argsort(err)  # the worst drawn last, on top
        art = ax.scatter(x[order], y[order], c=err[order], s=16, cmap="viridis", norm=norm_)
        rms = float(np.sqrt(np.nanmean(err**2)))
        ax.set_title(f"{title}\nposition RMS {rms:.1f} µm ({kind})", fontsize=10)
        ax.set_xlabel("x (mm)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, alpha=0.25)
    axes[0].set_ylabel("y (mm)")
    if art is not None:
        fig.colorbar(art, ax=list(axes), label="position error (µm, log scale)", shrink=0.9)
    fig.suptitle(
        "Pose error over the workspace: the pose computed from the six readings\nagainst the "
        "tracker's, platform positions seen from above",
        fontsize=11,
    )
    path = outdir / name
    fig.savefig(path, dpi=DPI, format="png")  # not cleared: see plot_parts.finish
    return path


# --- as figures to draw ----------------------------------------------------------------------------


def before_after_job(before: Diagnosis, after: Diagnosis, path: Path) -> FigureJob:
    """:func:`before_after` as a figure to draw at ``path``."""
    return FigureJob(path, lambda p: before_after(before, after, p.parent, p.name), 1.4)


def pose_error_job(diags: list[Diagnosis], path: Path) -> FigureJob:
    """:func:`pose_error_map` as a figure to draw at ``path``."""
    return FigureJob(path, lambda p: pose_error_map(diags, p.parent, p.name), 1.8)
