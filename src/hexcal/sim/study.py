"""The seed paper's Monte-Carlo study (§4), batched, with the direct forms and the refinement.

Protocol (Daney 1998, §4): the Left Hand robot, leg 3; for each N, 1000 random sets of N
constrained poses with uniform noise of half-width err_p (mm) on each position coordinate,
err_a (deg) about each platform axis, err_l (mm) on each reading; the mean over trials of
``‖a_c − a_r‖`` and ``‖b_c − b_r‖``. §3.2 runs on Type I sets (N = 4..50); §3.3 on Type II
sets for b (N = 4..30) and on Type III sets for a (N = 5..30) with b taken from an independent
Type II set of N1 = 7, then the offset by eq. (19) over the Type III poses.

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
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from hexcal.estimate import bound
from hexcal.estimate.layout import ParameterLayout
from hexcal.estimate.solvers import direct, paper, weighted
from hexcal.estimate.solvers.linalg import METHOD as lstsq_method
from hexcal.model.noise import NoiseSigmas
from hexcal.model.robot import Robot
from hexcal.sim.robots import left_hand
from hexcal.sim.simulate import NoiseModel, PoseRanges, Simulator

METHODS = ("paper", "direct", "refined")
SETS = ("type_i", "type_ii", "type_iii", "type_iii_known_b", "free")
#: The paper's factors at N = 7 (§5.1, §5.2).
PAPER_FACTORS = {
    "type_i": {"base": 13.0, "platform": 1.4},
    "type_ii": {"platform": 1.4},
    "type_iii": {"base": 2.8},
}


@dataclass(frozen=True)
class StudyConfig:
    """Everything that defines a study run; stored in its JSON output."""

    trials: int = 1000
    err_p_mm: float = 0.1
    err_a_deg: float = 0.01
    err_l_mm: float = 0.1
    noise: Literal["uniform", "gaussian"] = "uniform"
    leg: int = 3
    n_type_i: tuple[int, int] = (4, 50)
    n_type_ii: tuple[int, int] = (4, 30)
    n_type_iii: tuple[int, int] = (5, 30)
    n_type_ii_for_iii: int = 7
    #: Free-pose sets (Model 42 of the whole robot from all six leg lengths): the numbers of
    #: poses, and the trials per number (each is a 42-parameter least-squares fit, not a batch).
    n_free: tuple[int, ...] = (20, 40)
    trials_free: int = 300
    seed: int = 0
    ranges: PoseRanges = field(
        default_factory=lambda: PoseRanges(stroke_mm=30.0, tilt_deg=30.0, cone_deg=30.0)
    )


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


def _errors(est: np.ndarray, true: np.ndarray) -> float:
    return float(np.mean(np.linalg.norm(est - true, axis=-1)))


def _limit(est: np.ndarray | None, true: np.ndarray, bound_mm2: float) -> tuple[float, ...]:
    """(mean squared error mm², bound mm², efficiency, bias in σ) of a point estimate (T, 3)
    or of a scalar one (T,)."""
    nan = float("nan")
    if est is None:
        return nan, nan, nan, nan
    err = np.reshape(est - true, (len(est), -1))
    mse = float(np.mean(np.sum(err**2, axis=-1)))
    sd = err.std(axis=0)
    bias = float(np.max(np.abs(err.mean(axis=0)) / np.where(sd > 0, sd, np.inf)))
    return mse, bound_mm2, bound_mm2 / mse if mse > 0 else nan, bias


def run_study(
    config: StudyConfig = StudyConfig(),
    robot: Robot | None = None,
    on_sweep: Callable[[], None] | None = None,
) -> StudyResult:
    """Run the whole grid. Every trial of one N is drawn and solved in one batch; the pose-set
    sweeps (:data:`SWEEPS` of them) run on their own threads (numpy releases the GIL) with
    independent random streams, so the result does not depend on the scheduling. ``on_sweep``
    is called as each sweep ends (a progress bar)."""
    from concurrent.futures import ThreadPoolExecutor, as_completed

    robot = robot or left_hand()
    streams = np.random.SeedSequence(config.seed).spawn(5)
    sweeps = _SWEEPS
    with ThreadPoolExecutor(max_workers=min(5, os.cpu_count() or 1)) as pool:
        futures = [
            pool.submit(f, config, robot, np.random.default_rng(s))
            for f, s in zip(sweeps, streams, strict=True)
        ]
        for done in as_completed(futures):
            done.result()  # a sweep's error surfaces at once
            if on_sweep is not None:
                on_sweep()
        rows = [row for f in futures for row in f.result()]
    return StudyResult(config, rows)


class _Sweep:
    """What every sweep needs: simulator, weights, truth, and a row writer."""

    def __init__(self, config: StudyConfig, robot: Robot):
        self.config = config
        noise = NoiseModel(config.err_p_mm, config.err_a_deg, config.err_l_mm, config.noise)
        self.sim = Simulator(robot, ranges=config.ranges, noise=noise)
        self.sig = NoiseSigmas(
            noise.sigma_position_mm, noise.sigma_orientation_rad, noise.sigma_reading_mm
        )
        #: Without noise there is nothing to weight: the direct solution is already exact.
        self.noisy = min(self.sig.position_mm, self.sig.orientation_rad, self.sig.reading_mm) > 0
        self.k = config.leg - 1
        self.a, self.b, self.off = robot.a[self.k], robot.b[self.k], robot.offsets[self.k]
        self.ref_noise = config.err_p_mm if config.err_p_mm > 0 else float("nan")
        self.rows: list[dict] = []
        # The batched solves use the paper's normal equations (eq. 7): same numbers, faster.
        lstsq_method.set("normal")

    def add(
        self,
        pose_set,
        n,
        method,
        a=None,
        b=None,
        off=None,
        bound_a=None,
        bound_b=None,
        bound_off=None,
        **extra,
    ):
        nan = float("nan")
        ea = _errors(a, self.a) if a is not None else nan
        eb = _errors(b, self.b) if b is not None else nan
        eo = float(np.mean(np.abs(off - self.off))) if off is not None else nan
        la = _limit(a if bound_a is not None else None, self.a, bound_a or nan)
        lb = _limit(b if bound_b is not None else None, self.b, bound_b or nan)
        lo = _limit(off if bound_off is not None else None, self.off, bound_off or nan)
        self.rows.append(
            {
                "set": pose_set,
                "n": n,
                "method": method,
                "base_err_mm": ea,
                "platform_err_mm": eb,
                "offset_err_mm": eo,
                "base_factor": ea / self.ref_noise,
                "platform_factor": eb / self.ref_noise,
                "base_mse_mm2": la[0],
                "base_bound_mm2": la[1],
                "base_efficiency": la[2],
                "base_bias_sigma": la[3],
                "platform_mse_mm2": lb[0],
                "platform_bound_mm2": lb[1],
                "platform_efficiency": lb[2],
                "platform_bias_sigma": lb[3],
                "offset_mse_mm2": lo[0],
                "offset_bound_mm2": lo[1],
                "offset_efficiency": lo[2],
                "offset_bias_sigma": lo[3],
                "all_efficiency": extra.get("all_efficiency", nan),
            }
        )

    def bound_ok(self) -> bool:
        """The bound needs noise on every instrument (it inverts their covariance)."""
        return self.noisy

    def type_ii(self, n, rng):
        """b from T Type II sets of n poses by each method: ({method: (T, 3)}, the bound on
        E‖b̂ − b‖² mm² averaged over the sets, and the sets themselves: true and measured
        poses, and the refined fixed point C)."""
        sim, k = self.sim, self.k
        Pt, Rt = sim.type_ii(k, (self.config.trials, n), rng)
        P, R, _ = sim.measure(rng, Pt, Rt)
        b_p = paper.type_ii_paper(P, R)
        b_d, c_d = direct.type_ii_direct(P, R)
        b_r, c_r = weighted.refine_type_ii(P, R, b_d, c_d, self.sig) if self.noisy else (b_d, c_d)
        bnd = None
        if self.bound_ok():
            info = bound.information_type_ii(
                Pt, Rt, np.broadcast_to(self.b, (len(Pt), 3)), self.sig
            )
            bnd = float(bound.base_point_mse_bound(info, "type_ii").mean())
        return {"paper": b_p, "direct": b_d, "refined": b_r}, bnd, (Pt, Rt, P, R, c_r)


def _sweep_type_i(config: StudyConfig, robot: Robot, rng: np.random.Generator) -> list[dict]:
    sw = _Sweep(config, robot)
    sim, k = sw.sim, sw.k
    for n in range(config.n_type_i[0], config.n_type_i[1] + 1):
        Pt, Rt = sim.type_i(k, (config.trials, n), rng)
        P, R, rho = sim.measure(rng, Pt, Rt)
        length = rho[..., k] + sw.off
        b_p, a_p = paper.type_i_paper(P, R, length)
        b_d, a_d, u_d = direct.type_i_direct(P, R, length)
        b_r, a_r, _ = (
            weighted.refine_type_i(P, R, length, b_d, a_d, u_d, sw.sig)
            if sw.noisy
            else (b_d, a_d, u_d)
        )
        bounds: dict = {}
        if sw.bound_ok():
            v = Pt + (Rt @ sw.b[:, None])[..., 0] - sw.a  # true leg vectors (T, n, 3)
            true_len = np.linalg.norm(v, axis=-1)
            u = v[:, 0] / true_len[:, :1]
            T = config.trials
            info = bound.information_type_i(
                Pt,
                Rt,
                true_len,
                np.broadcast_to(sw.b, (T, 3)),
                np.broadcast_to(sw.a, (T, 3)),
                u,
                sw.sig,
            )
            cov = bound.bound(info)  # (b, a, u) once for both points
            bounds = {
                "bound_a": float(np.trace(cov[:, 3:6, 3:6], axis1=1, axis2=2).mean()),
                "bound_b": float(np.trace(cov[:, 0:3, 0:3], axis1=1, axis2=2).mean()),
            }
        sw.add("type_i", n, "paper", a_p, b_p, **bounds)
        sw.add("type_i", n, "direct", a_d, b_d, **bounds)
        sw.add("type_i", n, "refined", a_r, b_r, **bounds)
    return sw.rows


def _sweep_type_ii(config: StudyConfig, robot: Robot, rng: np.random.Generator) -> list[dict]:
    sw = _Sweep(config, robot)
    for n in range(config.n_type_ii[0], config.n_type_ii[1] + 1):
        est, bnd, _ = sw.type_ii(n, rng)
        for method, b in est.items():
            sw.add("type_ii", n, method, b=b, bound_b=bnd)
    return sw.rows


def _sweep_type_iii(config: StudyConfig, robot: Robot, rng: np.random.Generator) -> list[dict]:
    """The paper's §3.3: b from a Type II set of N1 poses, a and the offset from a Type III set
    of N poses. The paper's and the direct methods go in sequence (b, then a through it); the
    refinement fits both sets at once (:func:`~hexcal.estimate.solvers.weighted.refine_type_ii_iii`),
    so the Type III poses sharpen b too. The bound is the joint one of both sets; the offset's
    adds the mean clamped reading's own noise, σρ²/N."""
    sw = _Sweep(config, robot)
    sim, k = sw.sim, sw.k
    T = config.trials
    for n in range(config.n_type_iii[0], config.n_type_iii[1] + 1):
        bs, _, (Pt2, Rt2, P2, R2, c_r) = sw.type_ii(config.n_type_ii_for_iii, rng)
        Pt, Rt = sim.type_iii(k, (T, n), rng)
        P, R, rho = sim.measure(rng, Pt, Rt)
        r_k = rho[..., k]
        a_p = paper.type_iii_paper(P, R, bs["paper"])
        a_d, _ = direct.type_iii_direct(P, R, bs["direct"])
        a_s, rad_s = direct.type_iii_direct(P, R, bs["refined"])
        b_r = bs["refined"]
        if sw.noisy:
            a_s, rad_s = weighted.refine_type_iii(P, R, b_r, a_s, rad_s, sw.sig)
            b_r, _, a_r, rad_r = weighted.refine_type_ii_iii(
                P2, R2, P, R, b_r, c_r, a_s, rad_s, sw.sig
            )
        else:
            a_r, rad_r = a_s, rad_s
        bounds: dict = {}
        if sw.bound_ok():
            cov = bound.bound(
                bound.information_type_ii_iii(
                    Pt2,
                    Rt2,
                    Pt,
                    Rt,
                    np.broadcast_to(sw.b, (T, 3)),
                    np.broadcast_to(sw.a, (T, 3)),
                    sw.sig,
                )
            )
            bounds = {
                "bound_a": float(np.trace(cov[:, 6:9, 6:9], axis1=1, axis2=2).mean()),
                "bound_b": float(np.trace(cov[:, 0:3, 0:3], axis1=1, axis2=2).mean()),
                "bound_off": float((cov[:, 9, 9] + sw.sig.reading_mm**2 / n).mean()),
            }
        for method, a, b, off in (
            ("paper", a_p, bs["paper"], paper.offset_eq19(P, R, bs["paper"], a_p, r_k)),
            ("direct", a_d, bs["direct"], paper.offset_eq19(P, R, bs["direct"], a_d, r_k)),
            ("refined", a_r, b_r, rad_r - r_k.mean(axis=-1)),
        ):
            sw.add("type_iii", n, method, a, b, off, **bounds)
    return sw.rows


def _sweep_free(config: StudyConfig, robot: Robot, rng: np.random.Generator) -> list[dict]:
    """Model 42 of the whole robot from free poses (all six leg lengths, nothing clamped):
    the free-pose linear form per leg (the paper's method has none: its row is the linear
    seed), then the whole-robot refinement of :mod:`hexcal.estimate.refine` (from a design 1 mm off the
    truth when the linear seed's fit fails, as in ``hexcal calibrate``), whose whitening by each
    pose's 6×6 covariance is the first-order maximum likelihood of explicit leg-length
    constraints. The bound is ``(J_wᵀ J_w)⁻¹`` of the whitened leg-length Jacobian at the true
    geometry and poses; ``all_efficiency`` is tr(bound) / E‖θ̂ − θ‖² over all 42 parameters."""
    from hexcal.estimate.refine import _model, _whiteners
    from hexcal.estimate.refine_batch import refine_from_seeds_batch
    from hexcal.estimate.solvers.free import free_linear

    sw = _Sweep(config, robot)
    sim, k = sw.sim, sw.k
    T = config.trials_free
    lay = ParameterLayout.for_model(42)
    x_true = lay.pack(robot.a, robot.b, robot.offsets)
    # A lab's drawing is off the real robot by about a millimetre: the fallback start of a fit
    # that fails from the linear seed (as hexcal calibrate does).
    design = robot.with_geometry(
        robot.a + rng.normal(0, 1.0, (6, 3)),
        robot.b + rng.normal(0, 1.0, (6, 3)),
        robot.offsets + rng.normal(0, 1.0, 6),
    )
    design_x = lay.pack(design.a, design.b, design.offsets)
    for n in config.n_free:
        Pt, Rt = sim.free((T, n), rng)
        P, R, rho = sim.measure(rng, Pt, Rt)
        seeds, bounds = [], []
        for t in range(T):
            lin = [free_linear(P[t], R[t], rho[t, :, j]) for j in range(6)]
            a0 = np.array([s[1] for s in lin])
            b0 = np.array([s[0] for s in lin])
            off0 = np.array([s[2] for s in lin])
            seeds.append(lay.pack(a0, b0, off0))
            if sw.bound_ok():
                w = _whiteners(robot.a, robot.b, Pt[t], Rt[t], sw.sig)
                true_rho = sim.true_lengths(Pt[t], Rt[t]) - robot.offsets
                _, jac = _model(x_true, Pt[t], Rt[t], true_rho, robot.offsets, True)
                jw = np.einsum("mij,mjp->mip", w, jac).reshape(-1, lay.size)
                bounds.append(np.linalg.pinv(jw.T @ jw, hermitian=True))
        seeds_a = np.array(seeds)
        # Every trial's fit in one batch; each fit's start and retry as hexcal calibrate's.
        fits_a = (
            refine_from_seeds_batch(P, R, rho, seeds_a, design_x, np.zeros(6), True, sw.sig)[
                :, lay.geometry_slice
            ]
            if sw.noisy
            else seeds_a
        )
        extra: dict = {}
        if bounds:
            cov = np.mean(bounds, axis=0)
            ia, ib, io = lay.a_of_leg(k), lay.b_of_leg(k), lay.offset_column(k)
            extra = {
                "bound_a": float(np.trace(cov[ia, ia])),
                "bound_b": float(np.trace(cov[ib, ib])),
                "bound_off": float(cov[io, io]),
            }
        for method, x in (("direct", seeds_a), ("refined", fits_a)):
            all_eff = (
                float(np.trace(cov) / np.mean(np.sum((x - x_true) ** 2, axis=-1)))
                if bounds
                else float("nan")
            )
            sw.add(
                "free",
                n,
                method,
                x[:, lay.a_of_leg(k)],
                x[:, lay.b_of_leg(k)],
                x[:, lay.offset_column(k)],
                all_efficiency=all_eff,
                **extra,
            )
    return sw.rows


def _sweep_type_iii_known_b(
    config: StudyConfig, robot: Robot, rng: np.random.Generator
) -> list[dict]:
    """Type III with the true b: the sphere fit alone, against its own bound."""
    sw = _Sweep(config, robot)
    sim, k = sw.sim, sw.k
    T = config.trials
    b = np.broadcast_to(sw.b, (T, 3))
    for n in range(config.n_type_iii[0], config.n_type_iii[1] + 1):
        Pt, Rt = sim.type_iii(k, (T, n), rng)
        P, R, _ = sim.measure(rng, Pt, Rt)
        a_p = paper.type_iii_paper(P, R, b)
        a_d, rad_d = direct.type_iii_direct(P, R, b)
        a_r = weighted.refine_type_iii(P, R, b, a_d, rad_d, sw.sig)[0] if sw.noisy else a_d
        bnd = None
        if sw.bound_ok():
            info = bound.information_type_iii(Pt, Rt, b, np.broadcast_to(sw.a, (T, 3)), sw.sig)
            bnd = float(bound.base_point_mse_bound(info, "type_iii").mean())
        for method, a in (("paper", a_p), ("direct", a_d), ("refined", a_r)):
            sw.add("type_iii_known_b", n, method, a, bound_a=bnd)
    return sw.rows


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
        f"±{cfg.err_l_mm} mm reading; {cfg.trials} trials per N; leg {cfg.leg}"
    )
    style = {"paper": ("C3", "o"), "direct": ("C0", "s"), "refined": ("C2", "^")}
    fig, axes = _figure(nrows=1, ncols=len(keys), figsize=(5.5 * len(keys), 4.2), squeeze=False)
    for ax, (key, label) in zip(axes[0], keys, strict=False):
        for method in METHODS:
            n, e = result.curve(pose_set, method, key)
            c, m = style[method]
            ax.semilogy(n, e, color=c, marker=m, ms=3, lw=1.2, label=method)
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
        f"{cfg.trials} trials per N; leg {cfg.leg}",
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


#: The study's sweeps, one per pose set, each on its own thread.
_SWEEPS = (_sweep_type_i, _sweep_type_ii, _sweep_type_iii, _sweep_type_iii_known_b, _sweep_free)
SWEEPS = len(_SWEEPS)
