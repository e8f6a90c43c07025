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
"""

from __future__ import annotations

import csv
import json
import os
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path
from typing import Literal

import numpy as np

from hexcal.noise import NoiseSigmas
from hexcal.robot import Robot
from hexcal.simulate import NoiseModel, PoseRanges, Simulator
from hexcal.solvers import direct, paper, weighted
from hexcal.solvers.linalg import METHOD as lstsq_method

METHODS = ("paper", "direct", "refined")
SETS = ("type_i", "type_ii", "type_iii")
#: The paper's factors at N = 7 (§5.1, §5.2).
PAPER_FACTORS = {
    "type_i": {"base": 13.0, "platform": 1.4},
    "type_ii": {"platform": 1.4},
    "type_iii": {"base": 2.8},
}


def left_hand() -> Robot:
    """The seed paper's Left Hand robot (§4 table, converted to mm)."""
    text = resources.files("hexcal").joinpath("data/left_hand.json").read_text(encoding="utf-8")
    return Robot.model_validate_json(text)


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


def run_study(config: StudyConfig = StudyConfig(), robot: Robot | None = None) -> StudyResult:
    """Run the whole grid. Every trial of one N is drawn and solved in one batch; the three
    pose-set sweeps run on their own threads (numpy releases the GIL) with independent random
    streams, so the result does not depend on the scheduling."""
    from concurrent.futures import ThreadPoolExecutor

    robot = robot or left_hand()
    streams = np.random.SeedSequence(config.seed).spawn(3)
    sweeps = (_sweep_type_i, _sweep_type_ii, _sweep_type_iii)
    with ThreadPoolExecutor(max_workers=min(3, os.cpu_count() or 1)) as pool:
        futures = [
            pool.submit(f, config, robot, np.random.default_rng(s))
            for f, s in zip(sweeps, streams, strict=True)
        ]
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

    def add(self, pose_set, n, method, a=None, b=None, off=None):
        nan = float("nan")
        ea = _errors(a, self.a) if a is not None else nan
        eb = _errors(b, self.b) if b is not None else nan
        eo = float(np.mean(np.abs(off - self.off))) if off is not None else nan
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
            }
        )

    def type_ii(self, n, rng):
        """b from T Type II sets of n poses by each method: {method: (T, 3)}."""
        sim, k = self.sim, self.k
        P, R, _ = sim.measure(rng, *sim.type_ii(k, (self.config.trials, n), rng))
        b_p = paper.type_ii_paper(P, R)
        b_d, c_d = direct.type_ii_direct(P, R)
        b_r = weighted.refine_type_ii(P, R, b_d, c_d, self.sig)[0] if self.noisy else b_d
        return {"paper": b_p, "direct": b_d, "refined": b_r}


def _sweep_type_i(config: StudyConfig, robot: Robot, rng: np.random.Generator) -> list[dict]:
    sw = _Sweep(config, robot)
    sim, k = sw.sim, sw.k
    for n in range(config.n_type_i[0], config.n_type_i[1] + 1):
        P, R, rho = sim.measure(rng, *sim.type_i(k, (config.trials, n), rng))
        length = rho[..., k] + sw.off
        b_p, a_p = paper.type_i_paper(P, R, length)
        b_d, a_d, u_d = direct.type_i_direct(P, R, length)
        b_r, a_r, _ = (
            weighted.refine_type_i(P, R, length, b_d, a_d, u_d, sw.sig)
            if sw.noisy
            else (b_d, a_d, u_d)
        )
        sw.add("type_i", n, "paper", a_p, b_p)
        sw.add("type_i", n, "direct", a_d, b_d)
        sw.add("type_i", n, "refined", a_r, b_r)
    return sw.rows


def _sweep_type_ii(config: StudyConfig, robot: Robot, rng: np.random.Generator) -> list[dict]:
    sw = _Sweep(config, robot)
    for n in range(config.n_type_ii[0], config.n_type_ii[1] + 1):
        for method, b in sw.type_ii(n, rng).items():
            sw.add("type_ii", n, method, b=b)
    return sw.rows


def _sweep_type_iii(config: StudyConfig, robot: Robot, rng: np.random.Generator) -> list[dict]:
    sw = _Sweep(config, robot)
    sim, k = sw.sim, sw.k
    for n in range(config.n_type_iii[0], config.n_type_iii[1] + 1):
        bs = sw.type_ii(config.n_type_ii_for_iii, rng)
        P, R, rho = sim.measure(rng, *sim.type_iii(k, (config.trials, n), rng))
        r_k = rho[..., k]
        a_p = paper.type_iii_paper(P, R, bs["paper"])
        a_d, _ = direct.type_iii_direct(P, R, bs["direct"])
        a_s, rad_s = direct.type_iii_direct(P, R, bs["refined"])
        a_r, rad_r = (
            weighted.refine_type_iii(P, R, bs["refined"], a_s, rad_s, sw.sig)
            if sw.noisy
            else (a_s, rad_s)
        )
        sw.add(
            "type_iii", n, "paper", a_p, bs["paper"], paper.offset_eq19(P, R, bs["paper"], a_p, r_k)
        )
        sw.add(
            "type_iii",
            n,
            "direct",
            a_d,
            bs["direct"],
            paper.offset_eq19(P, R, bs["direct"], a_d, r_k),
        )
        sw.add("type_iii", n, "refined", a_r, bs["refined"], rad_r - r_k.mean(axis=-1))
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
            "paper_factors": PAPER_FACTORS,
            "rows": [{k: clean(v) for k, v in r.items()} for r in result.rows],
        },
        indent=1,
    )


def plot(result: StudyResult, outdir: str | Path) -> list[Path]:
    """PNG plots of the figures 5, 6, 9, 10 kind: mean error against N, methods side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    cfg = result.config
    noise_txt = (
        f"{cfg.noise} noise: ±{cfg.err_p_mm} mm position, ±{cfg.err_a_deg}° orientation, "
        f"±{cfg.err_l_mm} mm reading; {cfg.trials} trials per N; leg {cfg.leg}"
    )
    panels = [
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
    style = {"paper": ("C3", "o"), "direct": ("C0", "s"), "refined": ("C2", "^")}
    paths = []
    for pose_set, title, keys in panels:
        fig, axes = plt.subplots(1, len(keys), figsize=(5.5 * len(keys), 4.2), squeeze=False)
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
        path = outdir / f"study_{pose_set}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths


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
