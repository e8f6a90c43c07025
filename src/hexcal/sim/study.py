"""The seed paper's Monte-Carlo study (§4), batched, with the direct forms and the refinement.

Protocol (Daney 1998, §4): the Left Hand robot, leg 3; for each N, 1000 random sets of N
constrained poses with uniform noise of half-width err_p (mm) on each position coordinate,
err_a (deg) about each platform axis, err_l (mm) on each reading; the mean over trials of
``‖a_c − a_r‖`` and ``‖b_c − b_r‖``. §3.2 runs on Type I sets (N = 4..50); §3.3 on Type II
sets for b (N = 4..30) and on Type III sets for a (N = 5..30) with b taken from an independent
Type II set of N1 = 7, then the offset by eq. (19) over the Type III poses. By default the
sets are nested — each trial's first N poses of one set of the largest N — and
``StudyConfig(nested=False)`` draws a new set for every N as the paper did
(:mod:`hexcal.sim.study_sweeps`).

The paper's output/input factor divides the mean error by the noise, with the noise in cm and
degrees given the same number. The defaults keep that pairing: err_p = err_l = 0.1 mm
(0.01 cm) with err_a = 0.01 deg, and factor = mean error (mm) / err_p (mm).

Beyond the paper, every row also carries the statistical limit (:mod:`hexcal.estimate.bound`): the mean
squared error E‖x̂ − x‖² (mm²) of the base and platform points, its KCR bound for the same pose
sets (mean over trials of the trace of the bound, evaluated at the true poses), the efficiency
= bound / mean squared error (1: nothing left to gain), and the bias: the largest |mean error|
of a coordinate over its standard deviation. A fourth set, ``type_iii_known_b``, runs Type III
with the true b, so that its bound is that of the sphere fit alone. The bound is the Gaussian
one: with ``noise="uniform"`` it is computed for the same standard deviations and the
efficiencies are indicative only.
"""

from __future__ import annotations

import csv
import json
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from hexcal.model.robot import Robot
from hexcal.sim import study_sweeps as _sweeps
from hexcal.sim.robots import left_hand
from hexcal.sim.study_sweeps import StudyConfig

METHODS = ("paper", "direct", "refined")
SETS = ("type_i", "type_ii", "type_iii", "type_iii_known_b", "free")
#: The paper's factors at N = 7 (§5.1, §5.2).
PAPER_FACTORS = {
    "type_i": {"base": 13.0, "platform": 1.4},
    "type_ii": {"platform": 1.4},
    "type_iii": {"base": 2.8},
}


@dataclass
class StudyResult:
    config: StudyConfig
    rows: list[dict]

    def curve(self, pose_set: str, method: str, key: str) -> tuple[np.ndarray, np.ndarray]:
        rows = [r for r in self.rows if r["set"] == pose_set and r["method"] == method]
        return np.array([r["n"] for r in rows]), np.array([r[key] for r in rows])

    def factors(self, n: int = 7) -> dict[str, dict[str, dict[str, float]]]:
        """Output/input factors at N = n: {set: {method: {base, platform}}}."""
        out: dict = {}
        for r in self.rows:
            if r["n"] == n:
                out.setdefault(r["set"], {})[r["method"]] = {
                    k: r[f"{k}_factor"]
                    for k in ("base", "platform")
                    if np.isfinite(r[f"{k}_factor"])
                }
        return out


def run_study(
    config: StudyConfig | None = None,
    robot: Robot | None = None,
    on_sweep: Callable[[], None] | None = None,
) -> StudyResult:
    """Run the whole grid. The trials of one N are solved in one batch; the pose-set
    sweeps (:data:`SWEEPS` of them) run on their own threads (numpy releases the GIL) with
    independent random streams, so the result does not depend on the scheduling. ``on_sweep``
    is called as each sweep ends (a progress bar)."""
    from concurrent.futures import ThreadPoolExecutor, as_completed

    config = config or StudyConfig()
    robot = robot or left_hand()
    streams = np.random.SeedSequence(config.seed).spawn(5)
    sweeps = _sweeps.SWEEPS
    with ThreadPoolExecutor(max_workers=min(5, os.cpu_count() or 1)) as pool:
        # The costliest first (:data:`~hexcal.sim.study_sweeps.COST_ORDER`), so that the
        # threads end together; each sweep keeps its own stream, the rows their order.
        futures = {
            i: pool.submit(sweeps[i], config, robot, np.random.default_rng(streams[i]))
            for i in _sweeps.COST_ORDER
        }
        for done in as_completed(futures.values()):
            done.result()  # a sweep's error surfaces at once
            if on_sweep is not None:
                on_sweep()
        rows = [row for i in range(len(sweeps)) for row in futures[i].result()]
    return StudyResult(config, rows)


# -- output -------------------------------------------------------------------------------------
def write_csv(result: StudyResult, path: str | Path) -> None:
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=list(result.rows[0]))
        w.writeheader()
        w.writerows(result.rows)


def to_json(result: StudyResult, n: int = 7) -> str:
    def clean(v):
        return None if isinstance(v, float) and not np.isfinite(v) else v

    return json.dumps(
        {
            "config": asdict(result.config),
            "factors_at_n": n,
            "factors": result.factors(n),
            "efficiency": {str(m): efficiency(result, m) for m in (7, 20)},
            "paper_factors": PAPER_FACTORS,
            "rows": [{k: clean(v) for k, v in r.items()} for r in result.rows],
        },
        indent=1,
    )


def _figure(**kwargs):
    """A matplotlib figure on the Agg canvas, outside pyplot (no backend switched, no global
    list of figures), titles at the axes' top without measuring the tick labels to place them
    (where matplotlib puts them anyway: nothing sits above the panels)."""
    from matplotlib import rc_context
    from matplotlib.figure import Figure

    with rc_context({"axes.titley": 1.0}):
        fig = Figure(figsize=kwargs.pop("figsize"))
        return fig, fig.subplots(**kwargs)


#: Superscript digits and minus, for a log axis's tick labels written as plain text.
_SUPERSCRIPT = str.maketrans("0123456789-", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻")


def _plain_log_labels(ax) -> None:
    """Label ``ax``'s log-scaled y axis as matplotlib does (10⁻¹, 4×10⁻²), in plain text rather
    than mathtext: parsing and laying out each label glyph by glyph through mathtext was a
    third of a log figure's drawing."""
    from matplotlib.ticker import LogFormatterSciNotation

    class Plain(LogFormatterSciNotation):
        def __call__(self, x, pos=None):
            text = super().__call__(x, pos)
            if not text.startswith(r"$\mathdefault{"):
                return text
            text = text[len(r"$\mathdefault{") : -2].replace(r"\times", "×")
            mantissa, _, exponent = text.partition("^{")
            return mantissa + exponent.rstrip("}").translate(_SUPERSCRIPT)

    ax.yaxis.set_major_formatter(Plain(10))
    ax.yaxis.set_minor_formatter(Plain(10, labelOnlyBase=False))


def _design(cfg: StudyConfig) -> str:
    """The pose sets' design in a figure's subtitle."""
    return "nested pose sets" if cfg.nested else "a new pose set per N"


def _panels(cfg: StudyConfig) -> list[tuple[str, str, list[tuple[str, str]]]]:
    """(pose set, title, [(row key, label)]) of each figure of :func:`plot`."""
    return [
        (
            "type_i",
            "§3.2 — Type I (direction clamped)",
            [("base_err_mm", "base point a"), ("platform_err_mm", "platform point b")],
        ),
        (
            "type_ii",
            "§3.3.1 — Type II (direction + length clamped)",
            [("platform_err_mm", "platform point b")],
        ),
        (
            "type_iii",
            f"§3.3.2-3 — Type III (length clamped), b from {cfg.n_type_ii_for_iii} Type II poses",
            [("base_err_mm", "base point a"), ("offset_err_mm", "leg offset")],
        ),
    ]


def _plot_set(result: StudyResult, path: Path, pose_set: str) -> Path:
    """One figure of :func:`plot`: the mean error of ``pose_set``'s estimates against N."""
    cfg = result.config
    title, keys = next((t, k) for s, t, k in _panels(cfg) if s == pose_set)
    noise_txt = (
        f"{cfg.noise} noise: ±{cfg.err_p_mm} mm position, ±{cfg.err_a_deg}° orientation, "
        f"±{cfg.err_l_mm} mm reading; {cfg.trials} trials per N, {_design(cfg)}; leg {cfg.leg}"
    )
    style = {"paper": ("C3", "o"), "direct": ("C0", "s"), "refined": ("C2", "^")}
    fig, axes = _figure(nrows=1, ncols=len(keys), figsize=(5.5 * len(keys), 4.2), squeeze=False)
    for ax, (key, label) in zip(axes[0], keys, strict=False):
        for method in METHODS:
            n, e = result.curve(pose_set, method, key)
            c, m = style[method]
            ax.semilogy(n, e, color=c, marker=m, ms=3, lw=1.2, label=method)
        _plain_log_labels(ax)
        ax.set_xlabel("number of poses N")
        ax.set_ylabel(f"mean error of {label} (mm)")
        ax.grid(True, which="both", alpha=0.3)
        ax.axvline(7, color="0.6", lw=0.8, ls="--")
        ax.legend()
    fig.suptitle(f"{title}\n{noise_txt}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png")  # the suffix may be a temporary file's
    return path


def plot(result: StudyResult, outdir: str | Path) -> list[Path]:
    """PNG plots of the figures 5, 6, 9, 10 kind: mean error against N, methods side by side."""
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    return [
        _plot_set(result, outdir / f"study_{pose_set}.png", pose_set)
        for pose_set, _, _ in _panels(result.config)
    ]


def write_plots(result: StudyResult, outdir: str | Path) -> list[Path]:
    """Every PNG of the study (:func:`plot`'s, then :func:`plot_efficiency`'s), drawn on two
    cores where that pays (:mod:`hexcal.diagnosis.figure_pool`)."""
    from functools import partial

    # Imported before the fork, so that the copy has it too: imported by each of the two
    # processes, matplotlib cost 0.6 s of CPU twice.
    import matplotlib.backends.backend_agg
    import matplotlib.figure  # noqa: F401

    from hexcal.diagnosis.figure_pool import FigureJob, draw_all

    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    jobs = [
        FigureJob(outdir / f"study_{s}.png", partial(_plot_set, result, pose_set=s), 0.8)
        for s, _, _ in _panels(result.config)
    ]
    # The efficiency figure's ten panels cost about as much as the three others together: it
    # is taken first.
    jobs.append(
        FigureJob(
            outdir / "study_efficiency.png",
            lambda path: plot_efficiency(result, path.parent, path.name),
            2.4,
        )
    )
    return draw_all(jobs)


#: The estimates whose efficiency the study reports: (set, point, label).
EFFICIENCY_ROWS = (
    ("type_i", "base", "Type I, base point a"),
    ("type_i", "platform", "Type I, platform point b"),
    ("type_ii", "platform", "Type II, platform point b"),
    ("type_iii", "base", "Types II+III (§3.3), base point a"),
    ("type_iii", "platform", "Types II+III (§3.3), platform point b"),
    ("type_iii", "offset", "Types II+III (§3.3), leg offset"),
    ("type_iii_known_b", "base", "Type III (b known), base point a"),
    ("free", "base", "free poses (Model 42), base point a"),
    ("free", "platform", "free poses (Model 42), platform point b"),
    ("free", "offset", "free poses (Model 42), leg offset"),
)


def efficiency(result: StudyResult, n: int) -> dict[str, dict[str, dict[str, float]]]:
    """{"set/point": {method: {efficiency, bias_sigma, rms_mm, bound_rms_mm}}} at N = n."""
    out: dict = {}
    for pose_set, q, _ in EFFICIENCY_ROWS:
        for r in result.rows:
            if r["set"] == pose_set and r["n"] == n:
                out.setdefault(f"{pose_set}/{q}", {})[r["method"]] = {
                    "efficiency": r[f"{q}_efficiency"],
                    "bias_sigma": r[f"{q}_bias_sigma"],
                    "rms_mm": float(np.sqrt(r[f"{q}_mse_mm2"])),
                    "bound_rms_mm": float(np.sqrt(r[f"{q}_bound_mm2"])),
                }
    return out


def efficiency_table(result: StudyResult, ns: tuple[int, ...] = (7, 20)) -> str:
    """Efficiency (bound / mean squared error) and bias (σ) per method, as text."""
    lines = [
        "efficiency = KCR bound / mean squared error (1 = the statistical limit); bias = largest "
        "|mean error| / σ of a coordinate:",
        f"  {'estimate':<40}{'N':>3}{'bound RMS mm':>14}"
        + "".join(f"{m + ' eff':>13}{'bias':>7}" for m in METHODS),
    ]
    for n in ns:
        eff = efficiency(result, n)
        for pose_set, q, label in EFFICIENCY_ROWS:
            row = eff.get(f"{pose_set}/{q}")
            if not row:
                continue
            b = next(iter(row.values()))["bound_rms_mm"]
            lines.append(
                f"  {label:<40}{n:>3}{b:>14.4f}"
                + "".join(
                    f"{row[m]['efficiency']:>13.3f}{row[m]['bias_sigma']:>7.3f}"
                    if m in row
                    else f"{'—':>13}{'':>7}"
                    for m in METHODS
                )
            )
    return "\n".join(lines)


def plot_efficiency(
    result: StudyResult, outdir: str | Path, name: str = "study_efficiency.png"
) -> Path:
    """PNG ``outdir``/``name``: efficiency against N for every estimate and method."""
    style = {"paper": ("C3", "o"), "direct": ("C0", "s"), "refined": ("C2", "^")}
    cols = (len(EFFICIENCY_ROWS) + 1) // 2
    fig, axes = _figure(nrows=2, ncols=cols, figsize=(3.4 * cols, 7.2), sharey=True, squeeze=False)
    for ax in axes.flat[len(EFFICIENCY_ROWS) :]:
        ax.set_visible(False)
    for ax, (pose_set, q, label) in zip(axes.flat, EFFICIENCY_ROWS, strict=False):
        for method in METHODS:
            n, e = result.curve(pose_set, method, f"{q}_efficiency")
            if not len(n):
                continue
            c, m = style[method]
            ax.plot(n, e, color=c, marker=m, ms=3, lw=1.2, label=method)
        ax.axhline(1.0, color="0.4", lw=0.8)
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("number of poses N")
        ax.set_ylim(0, 1.15)
        ax.grid(True, alpha=0.3)
    for row in axes:
        row[0].set_ylabel("efficiency = bound / MSE")
    axes[0, 0].legend()
    cfg = result.config
    kind = "σ" if cfg.noise == "gaussian" else "uniform ±"
    fig.suptitle(
        f"efficiency against the KCR bound — {cfg.noise} noise: {kind}{cfg.err_p_mm} mm position, "
        f"{kind}{cfg.err_a_deg}° orientation, {kind}{cfg.err_l_mm} mm reading; "
        f"{cfg.trials} trials per N, {_design(cfg)}; leg {cfg.leg}",
        fontsize=9,
    )
    fig.tight_layout()
    path = Path(outdir) / name
    fig.savefig(path, dpi=110, format="png")  # the suffix may be a temporary file's
    return path


def factor_table(result: StudyResult, n: int = 7) -> str:
    """The N = n factors beside the paper's, as text."""
    f = result.factors(n)
    lines = [
        f"output/input noise factors at N = {n} (mean error / err_p):",
        f"  {'set':<28}{'quantity':<10}{'paper says':>11}" + "".join(f"{m:>10}" for m in METHODS),
    ]
    for pose_set, label in (
        ("type_i", "§3.2 Type I"),
        ("type_ii", "§3.3.1 Type II"),
        ("type_iii", "§3.3.2 Type III"),
    ):
        for q in ("base", "platform"):
            if pose_set == "type_ii" and q == "base":
                continue
            if pose_set == "type_iii" and q == "platform":
                continue
            ref = PAPER_FACTORS.get(pose_set, {}).get(q)
            ref_txt = f"≈{ref:g}" if ref is not None else "—"
            vals = "".join(f"{f[pose_set][m].get(q, float('nan')):>10.2f}" for m in METHODS)
            lines.append(f"  {label:<28}{q:<10}{ref_txt:>11}{vals}")
    return "\n".join(lines)


#: The number of sweeps (pose sets), each on its own thread.
SWEEPS = len(_sweeps.SWEEPS)
