"""The study's five pose-set sweeps (:mod:`hexcal.sim.study`): each draws its trials' poses,
solves them by the paper's, the direct and the refined methods, bounds them, and writes one row
per N and method.

Two designs (``StudyConfig.nested``):

* **nested** (the default): each trial draws one pose set of the largest N, and the set of N
  poses is its first N — common random numbers across N. The linear methods and the bounds
  are sums over the poses, so every N is solved from running sums of one set
  (``counts`` in :mod:`hexcal.estimate.solvers`, :mod:`hexcal.estimate.bound`), and so is
  the Type I and Type II refinements, their weights held at the first N's estimate
  (:func:`~hexcal.estimate.solvers.weighted.refine_type_i_nested`, ``refine_type_ii_nested``);
  the other refinements run N by N on the leading poses (views, nothing copied), the joint
  Types II+III fit from the N before's optimum. §3.3's Type II set of
  N1 poses is drawn once per trial and serves every N of its Type III set.
* **independent** (the paper's own): a new pose set for every N and trial, as drawn before the
  nested design (the same draws for the same seed).

Each N's mean error is unbiased in both, with the same variance (a trial's first N poses are N
independent draws); docs/methods.md says why and what changes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from hexcal.estimate import bound
from hexcal.estimate.layout import ParameterLayout
from hexcal.estimate.solvers import direct, paper, weighted
from hexcal.estimate.solvers.linalg import METHOD as lstsq_method
from hexcal.model.noise import NoiseSigmas
from hexcal.model.robot import Robot
from hexcal.sim.simulate import NoiseModel, PoseRanges, Simulator


@dataclass(frozen=True)
class StudyConfig:
    """Everything that defines a study run (:mod:`hexcal.sim.study`); stored in its JSON output."""

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
    #: Nested pose sets (common random numbers across N: one set of the largest N per trial,
    #: its first N poses for each N); False draws a new set for every N, as the paper did.
    nested: bool = True
    ranges: PoseRanges = field(
        default_factory=lambda: PoseRanges(stroke_mm=30.0, tilt_deg=30.0, cone_deg=30.0)
    )


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


def _trace_mean(cov: np.ndarray, block: slice) -> np.ndarray:
    """Mean over the trials (axis 0) of the trace of ``cov``'s block: (C,) from (T, C, p, p)."""
    return np.trace(cov[..., block, block], axis1=-2, axis2=-1).mean(axis=0)


class _Sweep:
    """What every sweep needs: simulator, weights, truth, the design's pose sets, a row
    writer."""

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

    def sets(self, ns) -> list[tuple[int, np.ndarray]]:
        """(poses to draw per trial, the counts N (C,) solved from them) of each pose set the
        design draws for the numbers of poses ``ns``: one set of the largest N (nested), or
        one set per N (independent)."""
        ns = [int(n) for n in ns]
        if not ns:
            return []
        if self.config.nested:
            counts = np.unique(ns)
            return [(int(counts[-1]), counts)]
        return [(n, np.array([n])) for n in ns]

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
                "n": int(n),
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

    def type_ii(self, n, counts, rng):
        """b from T Type II sets of n poses by each method, from the first counts[c] poses of
        each: ({method: (T, C, 3)}, the bound on E‖b̂ − b‖² mm² averaged over the sets (C,),
        and the sets themselves: true and measured poses, and the refined fixed point C
        (T, C, 3))."""
        sim, k = self.sim, self.k
        Pt, Rt = sim.type_ii(k, (self.config.trials, n), rng)
        P, R, _ = sim.measure(rng, Pt, Rt)
        b_p = paper.type_ii_paper(P, R, counts)
        b_d, c_d = direct.type_ii_direct(P, R, counts)
        b_r, c_r = b_d, c_d
        if self.noisy:
            # Every count's fit from one running sum, weighted at the first count's estimate.
            b_r, c_r = weighted.refine_type_ii_nested(P, R, counts, b_d[:, 0], self.sig)
        bnd = None
        if self.bound_ok():
            info = bound.information_type_ii(
                Pt, Rt, np.broadcast_to(self.b, (len(Pt), 3)), self.sig, counts
            )
            bnd = bound.base_point_mse_bound(info, "type_ii").mean(axis=0)
        return {"paper": b_p, "direct": b_d, "refined": b_r}, bnd, (Pt, Rt, P, R, c_r)


def sweep_type_i(config: StudyConfig, robot: Robot, rng: np.random.Generator) -> list[dict]:
    sw = _Sweep(config, robot)
    sim, k, T = sw.sim, sw.k, config.trials
    for n_draw, counts in sw.sets(range(config.n_type_i[0], config.n_type_i[1] + 1)):
        Pt, Rt = sim.type_i(k, (T, n_draw), rng)
        P, R, rho = sim.measure(rng, Pt, Rt)
        length = rho[..., k] + sw.off
        b_p, a_p = paper.type_i_paper(P, R, length, counts)
        b_d, a_d, u_d = direct.type_i_direct(P, R, length, counts)
        bounds: dict = {}
        if sw.bound_ok():
            v = Pt + (Rt @ sw.b[:, None])[..., 0] - sw.a  # true leg vectors (T, n, 3)
            true_len = np.linalg.norm(v, axis=-1)
            u = v[:, 0] / true_len[:, :1]
            info = bound.information_type_i(
                Pt,
                Rt,
                true_len,
                np.broadcast_to(sw.b, (T, 3)),
                np.broadcast_to(sw.a, (T, 3)),
                u,
                sw.sig,
                counts,
            )
            cov = bound.bound(info)  # (b, a, u) once for both points
            bounds = {
                "bound_a": _trace_mean(cov, slice(3, 6)),
                "bound_b": _trace_mean(cov, slice(0, 3)),
            }
        b_r, a_r = b_d, a_d
        if sw.noisy:
            # Every count's fit from one running sum, weighted at the first count's estimate.
            b_r, a_r, _ = weighted.refine_type_i_nested(
                P, R, length, counts, b_d[:, 0], u_d[:, 0], sw.sig
            )
        for i, n in enumerate(counts):
            at = {key: float(v[i]) for key, v in bounds.items()}
            sw.add("type_i", n, "paper", a_p[:, i], b_p[:, i], **at)
            sw.add("type_i", n, "direct", a_d[:, i], b_d[:, i], **at)
            sw.add("type_i", n, "refined", a_r[:, i], b_r[:, i], **at)
    return sw.rows


def sweep_type_ii(config: StudyConfig, robot: Robot, rng: np.random.Generator) -> list[dict]:
    sw = _Sweep(config, robot)
    for n_draw, counts in sw.sets(range(config.n_type_ii[0], config.n_type_ii[1] + 1)):
        est, bnd, _ = sw.type_ii(n_draw, counts, rng)
        for i, n in enumerate(counts):
            for method, b in est.items():
                sw.add("type_ii", n, method, b=b[:, i], bound_b=None if bnd is None else bnd[i])
    return sw.rows


def sweep_type_iii(config: StudyConfig, robot: Robot, rng: np.random.Generator) -> list[dict]:
    """The paper's §3.3: b from a Type II set of N1 poses, a and the offset from a Type III set
    of N poses. The paper's and the direct methods go in sequence (b, then a through it); the
    refinement fits both sets at once (:func:`~hexcal.estimate.solvers.weighted.refine_type_ii_iii`),
    so the Type III poses sharpen b too. The bound is the joint one of both sets; the offset's
    adds the mean clamped reading's own noise, σρ²/N. Nested, one Type II set per trial serves
    every N."""
    sw = _Sweep(config, robot)
    sim, k, T = sw.sim, sw.k, config.trials
    n1 = config.n_type_ii_for_iii
    for n_draw, counts in sw.sets(range(config.n_type_iii[0], config.n_type_iii[1] + 1)):
        bs, _, (Pt2, Rt2, P2, R2, c_r) = sw.type_ii(n1, [n1], rng)
        bs, c_r = {m: b[:, 0] for m, b in bs.items()}, c_r[:, 0]
        Pt, Rt = sim.type_iii(k, (T, n_draw), rng)
        P, R, rho = sim.measure(rng, Pt, Rt)
        r_k = rho[..., k]
        a_p = paper.type_iii_paper(P, R, bs["paper"], counts)
        a_d, _ = direct.type_iii_direct(P, R, bs["direct"], counts)
        a_s, rad_s = direct.type_iii_direct(P, R, bs["refined"], counts)
        bounds: dict = {}
        if sw.bound_ok():
            b_true, a_true = np.broadcast_to(sw.b, (T, 3)), np.broadcast_to(sw.a, (T, 3))
            info = bound.information_type_ii_iii(Pt2, Rt2, Pt, Rt, b_true, a_true, sw.sig, counts)
            cov = bound.bound(info)
            bounds = {
                "bound_a": _trace_mean(cov, slice(6, 9)),
                "bound_b": _trace_mean(cov, slice(0, 3)),
                "bound_off": (cov[..., 9, 9] + sw.sig.reading_mm**2 / counts).mean(axis=0),
            }
        joint = None  # the joint fit of the N before: the next N's start (nested sets)
        for i, n in enumerate(counts):
            p, r, rk = P[:, :n], R[:, :n], r_k[:, :n]
            b_r, a_r, rad_r = bs["refined"], a_s[:, i], rad_s[:, i]
            if sw.noisy:
                if joint is None:
                    a_r, rad_r = weighted.refine_type_iii(p, r, b_r, a_r, rad_r, sw.sig)
                    joint = (b_r, c_r, a_r, rad_r)
                # Run to its optimum, the fit does not depend on its start but for rounding.
                joint = weighted.refine_type_ii_iii(P2, R2, p, r, *joint, sw.sig)
                b_r, _, a_r, rad_r = joint
            at = {key: float(v[i]) for key, v in bounds.items()}
            b_p, b_d = bs["paper"], bs["direct"]
            for method, a, b, off in (
                ("paper", a_p[:, i], b_p, paper.offset_eq19(p, r, b_p, a_p[:, i], rk)),
                ("direct", a_d[:, i], b_d, paper.offset_eq19(p, r, b_d, a_d[:, i], rk)),
                ("refined", a_r, b_r, rad_r - rk.mean(axis=-1)),
            ):
                sw.add("type_iii", n, method, a, b, off, **at)
    return sw.rows


def sweep_type_iii_known_b(
    config: StudyConfig, robot: Robot, rng: np.random.Generator
) -> list[dict]:
    """Type III with the true b: the sphere fit alone, against its own bound."""
    sw = _Sweep(config, robot)
    sim, k, T = sw.sim, sw.k, config.trials
    b = np.broadcast_to(sw.b, (T, 3))
    for n_draw, counts in sw.sets(range(config.n_type_iii[0], config.n_type_iii[1] + 1)):
        Pt, Rt = sim.type_iii(k, (T, n_draw), rng)
        P, R, _ = sim.measure(rng, Pt, Rt)
        a_p = paper.type_iii_paper(P, R, b, counts)
        a_d, rad_d = direct.type_iii_direct(P, R, b, counts)
        bnd = None
        if sw.bound_ok():
            a_true = np.broadcast_to(sw.a, (T, 3))
            info = bound.information_type_iii(Pt, Rt, b, a_true, sw.sig, counts=counts)
            bnd = bound.base_point_mse_bound(info, "type_iii").mean(axis=0)
        for i, n in enumerate(counts):
            a_r = a_d[:, i]
            if sw.noisy:
                a_r = weighted.refine_type_iii(P[:, :n], R[:, :n], b, a_r, rad_d[:, i], sw.sig)[0]
            for method, a in (("paper", a_p[:, i]), ("direct", a_d[:, i]), ("refined", a_r)):
                sw.add("type_iii_known_b", n, method, a, bound_a=None if bnd is None else bnd[i])
    return sw.rows


def _free_seeds(P, R, rho, counts, lay: ParameterLayout) -> np.ndarray:
    """The free-pose linear form of every leg (:mod:`hexcal.estimate.solvers.free`), from the
    first counts[c] poses of each set, packed: (T, C, p). P (T, n, 3) mm, R (T, n, 3, 3),
    rho (T, n, 6) mm."""
    from hexcal.estimate.solvers.free import free_system
    from hexcal.estimate.solvers.linalg import lstsq

    legs = []
    for j in range(6):
        m, y = free_system(P, R, rho[..., j], None)
        legs.append(lstsq(m, y, rows=counts))
    lin = np.stack(legs, axis=-2)  # (T, C, 6, 17): b, a, c_ij, s, Δ
    x = np.zeros((*lin.shape[:2], lay.size))
    lay.a(x)[:] = lin[..., 3:6]  # the layout's own views: packed as lay.pack packs
    lay.b(x)[:] = lin[..., :3]
    x[..., lay.offsets_slice] = lin[..., 16]
    return x


def _free_bounds(sw: _Sweep, Pt, Rt, counts, lay: ParameterLayout) -> np.ndarray:
    """The bound (T, C, p, p) of each set's first counts[c] true poses: ``(J_wᵀ J_w)⁻¹`` of
    the whitened leg-length Jacobian at the true geometry."""
    from hexcal.estimate.refine import _model, _whiteners

    robot = sw.sim.robot
    T, n = Pt.shape[:2]
    P, R = Pt.reshape(-1, 3), Rt.reshape(-1, 3, 3)
    x_true = lay.pack(robot.a, robot.b, robot.offsets)
    w = _whiteners(robot.a, robot.b, P, R, sw.sig)
    true_rho = sw.sim.true_lengths(P, R) - robot.offsets
    _, jac = _model(x_true, P, R, true_rho, robot.offsets, True)
    jw = np.einsum("mij,mjp->mip", w, jac).reshape(T, n * 6, lay.size)
    info = np.stack([jw[:, : 6 * c].swapaxes(1, 2) @ jw[:, : 6 * c] for c in counts], axis=1)
    return bound.bound(info)


def sweep_free(config: StudyConfig, robot: Robot, rng: np.random.Generator) -> list[dict]:
    """Model 42 of the whole robot from free poses (all six leg lengths, nothing clamped):
    the free-pose linear form per leg (the paper's method has none: its row is the linear
    seed), then the whole-robot refinement of :mod:`hexcal.estimate.refine` (from a design 1 mm off the
    truth when the linear seed's fit fails, as in ``hexcal calibrate``), whose whitening by each
    pose's 6×6 covariance is the first-order maximum likelihood of explicit leg-length
    constraints. The bound is ``(J_wᵀ J_w)⁻¹`` of the whitened leg-length Jacobian at the true
    geometry and poses; ``all_efficiency`` is tr(bound) / E‖θ̂ − θ‖² over all 42 parameters."""
    from hexcal.estimate.refine_batch import refine_from_seeds_batch

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
    ia, ib, io = lay.a_of_leg(k), lay.b_of_leg(k), lay.offset_column(k)
    for n_draw, counts in sw.sets(config.n_free):
        Pt, Rt = sim.free((T, n_draw), rng)
        P, R, rho = sim.measure(rng, Pt, Rt)
        seeds = _free_seeds(P, R, rho, counts, lay)
        covs = _free_bounds(sw, Pt, Rt, counts, lay).mean(axis=0) if sw.bound_ok() else None
        for i, n in enumerate(counts):
            seed = seeds[:, i]
            # Every trial's fit in one batch; each fit's start and retry as hexcal calibrate's.
            fit = seed
            if sw.noisy:
                fit = refine_from_seeds_batch(
                    P[:, :n], R[:, :n], rho[:, :n], seed, design_x, np.zeros(6), True, sw.sig
                )[:, lay.geometry_slice]
            extra: dict = {}
            if covs is not None:
                cov = covs[i]
                extra = {
                    "bound_a": float(np.trace(cov[ia, ia])),
                    "bound_b": float(np.trace(cov[ib, ib])),
                    "bound_off": float(cov[io, io]),
                }
            for method, x in (("direct", seed), ("refined", fit)):
                all_eff = (
                    float(np.trace(cov) / np.mean(np.sum((x - x_true) ** 2, axis=-1)))
                    if covs is not None
                    else float("nan")
                )
                sw.add(
                    "free",
                    n,
                    method,
                    x[:, ia],
                    x[:, ib],
                    x[:, io],
                    all_efficiency=all_eff,
                    **extra,
                )
    return sw.rows


#: The study's sweeps, one per pose set, each on its own thread.
SWEEPS = (sweep_type_i, sweep_type_ii, sweep_type_iii, sweep_type_iii_known_b, sweep_free)
#: The sweeps' indices, costliest first (nested, at the defaults: Types II+III 0.7 s of one
#: core, Type I 0.7 s, free poses 0.65 s, Type III with b known 0.3 s, Type II 0.17 s).
COST_ORDER = (2, 0, 4, 3, 1)
