"""Monte-Carlo efficiency of the whole-robot refinement on a calibration session.

One set of true poses (a whole session: every leg's clamped steps and free poses, as
:func:`hexcal.sim.session_sim.simulate_session` plans them) is measured again and again with fresh
noise; each trial is refined from the leg lengths alone and with the clamps' constraints
(:mod:`hexcal.estimate.clamp_rows`). The bound is the Cramér–Rao bound of the full likelihood,
computed apart from the estimator (:func:`fisher_bound`): the Fisher information of every
measured number — each pose's tracker position and orientation and its six readings, at the
stated noise — with the true poses, the robot's 42 parameters and each clamp's unknown as the
parameters, the clamps holding as constraints (the constrained Cramér–Rao bound).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.linalg import null_space
from scipy.spatial.transform import Rotation

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
    bound = np.diag(fisher_bound(truth, P, R, steps, sig))

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


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def fisher_bound(
    truth: Robot, P: np.ndarray, R: np.ndarray, steps: ClampSteps, sig: NoiseSigmas
) -> np.ndarray:
    """The Cramér–Rao bound (42, 42) on Model 42's parameters (a, b, offsets in
    :data:`LAYOUT`'s order; mm²) from a session's true poses P (M, 3) mm, R (M, 3, 3), its
    clamped ``steps`` and the noise ``sig``, written from the measurement model alone — no
    estimator's code:

    - measured: each pose's position (σ_p per axis), its orientation (a rotation of σ_θ about
      each platform axis) and its six readings ρ_k = |P + R b_k − a_k| − offset_k (σ_ρ);
    - unknown: the 42 parameters, each pose's true position and rotation, and each clamp's own
      unknown — a unit direction u (Type I), a point C (Type II), a length r (Type III);
    - constraints g = 0 on every pose of a step: the leg vector P + R b_k − a_k along u,
      P + R b_k = C, or |P + R b_k − a_k| = r.

    With J the whitened Jacobian of the measurements' means and U a basis of the null space of
    the constraints' Jacobian, the bound is U (Uᵀ JᵀJ U)⁻¹ Uᵀ (Gorman & Hero's constrained
    bound); Jacobians by central differences."""
    m = len(P)
    # The clamps' unknowns at the truth, from the first pose of each step.
    nus = []
    for s, kind in enumerate(steps.kind):
        i = int(np.where(steps.group == s)[0][0])
        k = steps.leg[s]
        v = P[i] + R[i] @ truth.b[k] - truth.a[k]
        nus.append(
            {"direction": _unit(v), "direction+length": v + truth.a[k]}.get(
                kind.value, np.array([np.linalg.norm(v)])
            )
        )
    sizes = [len(n) for n in nus]
    theta0 = LAYOUT.pack(truth.a, truth.b, truth.offsets)
    phi0 = np.concatenate([theta0, P.ravel(), np.zeros(3 * m), *nus])
    n_theta = len(theta0)
    starts = n_theta + 6 * m + np.concatenate([[0], np.cumsum(sizes)])

    def split(phi: np.ndarray):
        a = phi[LAYOUT.a_slice].reshape(6, 3)
        b = phi[LAYOUT.b_slice].reshape(6, 3)
        off = phi[LAYOUT.offsets_slice]
        pos = phi[n_theta : n_theta + 3 * m].reshape(m, 3)
        rot = (
            R
            @ Rotation.from_rotvec(phi[n_theta + 3 * m : n_theta + 6 * m].reshape(m, 3)).as_matrix()
        )
        return a, b, off, pos, rot

    def means(phi: np.ndarray) -> np.ndarray:
        a, b, off, pos, rot = split(phi)
        legs = pos[:, None, :] + np.einsum("mij,kj->mki", rot, b) - a[None]
        rho = np.linalg.norm(legs, axis=2) - off
        delta = phi[n_theta + 3 * m : n_theta + 6 * m]
        return np.concatenate(
            [
                pos.ravel() / sig.position_mm,
                delta / sig.orientation_rad,
                rho.ravel() / sig.reading_mm,
            ]
        )

    def constraints(phi: np.ndarray) -> np.ndarray:
        a, b, _, pos, rot = split(phi)
        out = []
        for s, kind in enumerate(steps.kind):
            nu = phi[starts[s] : starts[s + 1]]
            k = steps.leg[s]
            idx = steps.group == s
            v = pos[idx] + rot[idx] @ b[k] - a[k]
            if kind.value == "direction":
                out += [(v - np.linalg.norm(v, axis=1, keepdims=True) * nu).ravel(), [nu @ nu - 1]]
            elif kind.value == "direction+length":
                out.append((v + a[k] - nu).ravel())
            else:
                out.append(np.linalg.norm(v, axis=1) - nu[0])
        return np.concatenate(out) if out else np.zeros(0)

    # Which pose each row depends on (−1: none): a pose's rows depend on its own unknowns only,
    # so one difference moves a coordinate of every pose at once.
    poses = np.arange(m)
    mean_owner = np.concatenate([np.repeat(poses, 3), np.repeat(poses, 3), np.repeat(poses, 6)])
    per_step = {"direction": 3, "direction+length": 3, "length": 1}
    con_owner: list[np.ndarray] = []
    for s, kind in enumerate(steps.kind):
        con_owner.append(np.repeat(np.where(steps.group == s)[0], per_step[kind.value]))
        if kind.value == "direction":
            con_owner.append(np.array([-1]))
    owner = np.concatenate(con_owner).astype(int) if con_owner else np.zeros(0, int)
    J = _jacobian(means, phi0, mean_owner, n_theta, m)
    G = _jacobian(constraints, phi0, owner, n_theta, m)
    U = null_space(G, rcond=1e-9) if len(G) else np.eye(len(phi0))
    full = U @ np.linalg.inv(U.T @ (J.T @ J) @ U) @ U.T
    return full[:n_theta, :n_theta]


def _jacobian(f, x0: np.ndarray, owner: np.ndarray, start: int, m: int, h: float = 1e-6):
    """∂f/∂x at x0 by central differences, (len f, len x). ``x0[start : start + 6m]`` are M
    poses' unknowns (3m positions, then 3m rotations); row r of f depends on pose owner[r]'s
    alone (−1: on none), so each of the six coordinates is moved in every pose at once."""
    jac = np.zeros((len(owner), len(x0)))
    pose_cols = set(range(start, start + 6 * m))
    for i in [i for i in range(len(x0)) if i not in pose_cols]:
        dx = np.zeros_like(x0)
        dx[i] = h
        jac[:, i] = (f(x0 + dx) - f(x0 - dx)) / (2 * h)
    rows = np.where(owner >= 0)[0]
    for c in range(6):
        block, coord = divmod(c, 3)  # positions, then rotations; x, y, z
        cols = start + 3 * m * block + 3 * np.arange(m) + coord
        dx = np.zeros_like(x0)
        dx[cols] = h
        diff = (f(x0 + dx) - f(x0 - dx)) / (2 * h)
        jac[rows, cols[owner[rows]]] = diff[rows]
    return jac


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
