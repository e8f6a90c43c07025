"""Monte-Carlo efficiency of the whole-robot refinement on a calibration session.

One set of true poses (a whole session: every leg's clamped steps and free poses, as
:func:`hexcal.sim.session_sim.simulate_session` plans them) is measured again and again with fresh
noise; each trial is refined from the leg lengths alone and with the clamps' constraints
(:mod:`hexcal.estimate.clamp_rows`). The bound is the Cramér–Rao bound of the full likelihood (lengths
and clamps, the steps' nuisance unknowns eliminated): the covariance ``(J_wᵀ J_w)⁻¹`` that the
clamp-aware refinement reports on noise-free measurements of the same poses, i.e. evaluated at
the truth.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from hexcal.estimate.clamp_rows import ClampSteps
from hexcal.estimate.layout import ParameterLayout
from hexcal.estimate.refine import refine
from hexcal.model.noise import NoiseSigmas
from hexcal.model.robot import Robot
from hexcal.sim.session_sim import SessionPlan, simulate_session
from hexcal.sim.simulate import NoiseModel

#: The fitted vector: Model 42, no effects.
LAYOUT = ParameterLayout.for_model(42)
#: Parameter blocks reported: base points, platform points, leg offsets (Model 42 order).
BLOCKS = {"base": LAYOUT.a_slice, "platform": LAYOUT.b_slice, "offset": LAYOUT.offsets_slice}
METHODS = ("lengths", "clamps")


@dataclass(frozen=True)
class BlockFigures:
    """One block of parameters over the trials: root mean squared error (mm), the bound's RMS
    (mm), efficiency = bound / MSE (summed over the block), and the largest |mean error| of a
    coordinate over its standard deviation."""

    rms_mm: float
    bound_rms_mm: float
    efficiency: float
    bias_sigma: float


def session_efficiency(
    design: Robot,
    noise: NoiseModel,
    trials: int = 200,
    seed: int = 0,
    plan: SessionPlan | None = None,
) -> dict[str, dict[str, BlockFigures]]:
    """{method: {block: figures}} for ``trials`` noisy copies of one simulated session.

    ``noise`` Gaussian, its sigmas stated to the refinement; ``plan`` the session's pose
    counts (default: :class:`SessionPlan`'s, 184 poses). Poses and true robot are drawn from
    ``seed``, the noise of trial t from ``seed + 1 + t``.
    """
    plan = plan or SessionPlan()
    clean = replace(plan, noise=NoiseModel(), resolution=None)  # the true poses and readings
    meas, truth = simulate_session(design, seed, clean)
    P, R, rho = meas.position, meas.rotations.as_matrix(), meas.readings
    steps = ClampSteps.from_table(meas.leg, meas.constraint, meas.step)
    sig = NoiseSigmas(noise.sigma_position_mm, noise.sigma_orientation_rad, noise.sigma_reading_mm)
    true_x = LAYOUT.pack(truth.a, truth.b, truth.offsets)
    exact = refine(P, R, rho, truth.a, truth.b, truth.offsets, True, sig, clamps=steps)
    bound = np.diag(exact.cov)

    errors: dict[str, list[np.ndarray]] = {m: [] for m in METHODS}
    for t in range(trials):
        rng = np.random.default_rng(seed + 1 + t)
        Pn, Rn, rn = noise.apply(rng, P, R, rho)
        lengths = refine(Pn, Rn, rn, truth.a, truth.b, truth.offsets, True, sig)
        clamped = refine(Pn, Rn, rn, lengths.a, lengths.b, lengths.offsets(truth.offsets), True,
                         sig, clamps=steps)  # fmt: skip
        errors["lengths"].append(lengths.x - true_x)
        errors["clamps"].append(clamped.x - true_x)
    out: dict[str, dict[str, BlockFigures]] = {}
    for method, errs in errors.items():
        e = np.array(errs)
        out[method] = {}
        for name, sl in BLOCKS.items():
            mse = float(np.mean(np.sum(e[:, sl] ** 2, axis=1)))
            bnd = float(np.sum(bound[sl]))
            sd = e[:, sl].std(axis=0)
            out[method][name] = BlockFigures(
                rms_mm=float(np.sqrt(mse / e[:, sl].shape[1])),
                bound_rms_mm=float(np.sqrt(bnd / e[:, sl].shape[1])),
                efficiency=bnd / mse,
                bias_sigma=float(np.max(np.abs(e[:, sl].mean(axis=0)) / sd)),
            )
    return out


def efficiency_table(figures: dict[str, dict[str, BlockFigures]]) -> str:
    """Markdown table of :func:`session_efficiency`'s figures."""
    lines = [
        "| refinement | block | bound RMS mm | RMS error mm | efficiency | bias |",
        "|---|---|---|---|---|---|",
    ]
    label = {"lengths": "leg lengths only", "clamps": "lengths + clamps"}
    for method, blocks in figures.items():
        for name, f in blocks.items():
            lines.append(
                f"| {label[method]} | {name} | {f.bound_rms_mm:.4f} | {f.rms_mm:.4f} | "
                f"{f.efficiency:.2f} | {f.bias_sigma:.2f} σ |"
            )
    return "\n".join(lines)
