"""Statistical refinement of the geometry over every recorded pose and all six legs.

The fit minimises the leg-length residual ``|P + R b_k − a_k| − ρ_k − Δρ_k`` whitened by each
pose's full 6×6 covariance (the six legs share the pose's tracker noise; see
:mod:`hexcal.model.noise`), by Levenberg–Marquardt on the normal equations
(:mod:`hexcal.estimate.lm`), accumulated pose block by pose block
(:mod:`hexcal.estimate.leg_rows`; with the clamp rows, the steps' nuisance unknowns eliminated
by their Schur complement, :mod:`hexcal.estimate.clamp_normal`): time and memory grow linearly
with the poses. The covariance depends on the geometry, so it is evaluated at the linear seed,
the fit is run, and it is re-evaluated at the solution for a second fit.

The parameter covariance is ``(JᵀJ)⁻¹`` of the whitened Jacobian. With the instruments' noise
stated, it is scaled by ``max(1, χ²/dof)`` (an under-fitting model widens the intervals, never
narrows them); without it, the noise level is estimated from the residual and the covariance
scaled by ``χ²/dof``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from hexcal.errors import RefusedError
from hexcal.estimate.clamp_normal import ClampProblem
from hexcal.estimate.clamp_rows import ClampSteps, Nuisance
from hexcal.estimate.layout import ParameterLayout
from hexcal.estimate.leg_rows import (
    LegData,
    Normal,
    leg_normal,
    leg_residuals,
    pose_precisions,
)
from hexcal.estimate.lm import minimise
from hexcal.estimate.quantiles import norm_ppf, t_ppf
from hexcal.model.noise import DEFAULT_SIGMAS, NoiseSigmas, leg_whiteners

#: Function evaluations one least-squares pass may take (a converging fit takes about 10): a
#: fit that needs more is pulled somewhere by poses that do not belong (:class:`FitStalled`).
#: A nearly degenerate fit (a spline along the legs' inclination that the joints' heights
#: almost absorb: a scaled eigenvalue of 1e-10) takes 240 to its minimum, and a fold of its
#: cross-validation, starting at the full fit's optimum, up to 430.
MAX_NFEV = 500


class FitStalled(RefusedError, ValueError):
    """The refinement did not converge within :data:`MAX_NFEV` evaluations, or its residual is
    not finite. ``rows`` (0-based) are the poses with the largest whitened residual there: the
    ones pulling the fit."""

    def __init__(self, rows: list[int], why: str):
        self.rows = rows
        super().__init__(why)


def _stalled(x, d: LegData, lay: ParameterLayout, what: str) -> FitStalled:
    """The stall, naming the rows with the largest residual at ``x`` (the parameters of
    ``lay``)."""
    with np.errstate(all="ignore"):
        res = leg_residuals(x[None, : lay.size], d, lay)[0]
    norm = np.linalg.norm(res, axis=1)
    norm = np.where(np.isfinite(norm), norm, np.inf)
    rows = [int(i) for i in np.argsort(-norm)[:3]]
    return FitStalled(rows, what)


#: Relative eigenvalue of the scaled normal matrix below which a direction is not determined.
NULL_TOL = 1e-10
#: Variance inflation (σ against σ if it were the only unknown, squared) beyond which a
#: parameter is reported as not separable from the parameters it correlates with.
VIF_LIMIT = 1e6


def parameter_names(fit_offsets: bool) -> list[str]:
    """a1.x … a6.z, b1.x … b6.z, then offset1 … offset6 when fitted."""
    return ParameterLayout(fit_offsets).names()


@dataclass
class Refinement:
    """Result of :func:`refine`. Arrays in mm; ``residuals`` (M, 6) are length − prediction."""

    names: list[str]
    x: np.ndarray
    cov: np.ndarray
    sigma: np.ndarray
    ci95: np.ndarray
    corr: np.ndarray
    chi2: float
    dof: int
    noise_scale: float
    noise_source: str
    residuals: np.ndarray
    status: list[str]
    notes: list[str] = field(default_factory=list)
    strong_correlations: list[tuple[str, str, float]] = field(default_factory=list)
    nfev: int = 0
    success: bool = True
    whitened_jacobian: np.ndarray | None = None  #: (6M, p) at the solution
    whitened_residual: np.ndarray | None = None  #: (6M,)
    whiteners: np.ndarray | None = None  #: (M, 6, 6) W with W Σ Wᵀ = I
    #: Computes the two whitened arrays above when first asked for (they take 6M × p floats)
    _whiten: Callable[[], tuple[np.ndarray, np.ndarray]] | None = field(default=None, repr=False)
    #: With clamp rows (``refine(clamps=...)``): the steps and their fitted nuisance values;
    #: the whitened arrays above are then left None (their rows are not the six leg lengths).
    clamp_steps: ClampSteps | None = None
    clamp_nuisance: Nuisance | None = None
    #: Started from the design's geometry, the linear seed's fit having failed
    #: (:func:`hexcal.estimate.calibrate.refine_from_seeds`)
    from_design: bool = False
    #: What later stages derive from this fit once (e.g. the diagnosis' orthonormal basis of
    #: the whitened Jacobian), by name
    derived: dict = field(default_factory=dict, repr=False, compare=False)

    def value(self, name: str) -> float:
        return float(self.x[self.names.index(name)])

    def whitened(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(whitened Jacobian (6M, p), whitened residual (6M,), whiteners (M, 6, 6)) at the
        solution. A refinement with clamp rows has none: asking for them is a bug."""
        if self.whitened_jacobian is None and self._whiten is not None:
            self.whitened_jacobian, self.whitened_residual = self._whiten()
        jw, rw, w = self.whitened_jacobian, self.whitened_residual, self.whiteners
        if jw is None or rw is None or w is None:
            raise ValueError(
                "this refinement has no whitened arrays (fitted with clamp rows, whose rows are "
                "not the six leg lengths)"
            )
        return jw, rw, w

    @property
    def exceeds_stated_noise(self) -> bool:
        """χ²/dof above what the stated noise allows (4σ of χ²/dof, √(2/dof) each): the model
        misses something. Always False when the noise level was estimated."""
        return (
            self.noise_source == "instruments"
            and self.chi2 / self.dof > 1.0 + 4.0 * (2.0 / self.dof) ** 0.5
        )

    @property
    def layout(self) -> ParameterLayout:
        """Where a, b, the offsets (when fitted) and the effect parameters sit in :attr:`x`."""
        return ParameterLayout.of_vector(self.x, "offset1" in self.names)

    @property
    def a(self) -> np.ndarray:
        """The fitted base points (6, 3) mm."""
        return self.layout.a(self.x)

    @property
    def b(self) -> np.ndarray:
        """The fitted platform points (6, 3) mm."""
        return self.layout.b(self.x)

    def offsets(self, fixed: np.ndarray) -> np.ndarray:
        """The leg offsets (6,) mm: fitted, else ``fixed`` (6,) mm (the drawing's)."""
        return self.layout.offsets(self.x, np.asarray(fixed, float))

    @property
    def rms_mm(self) -> float:
        """Root mean square of the leg-length residual over every pose and leg, mm."""
        return float(np.sqrt(np.mean(self.residuals**2)))

    def ci95_of(self, prefix: str) -> np.ndarray:
        idx = [i for i, n in enumerate(self.names) if n.startswith(prefix)]
        return self.ci95[idx]


def _whiteners(a, b, P, R, sig: NoiseSigmas) -> np.ndarray:
    """W (M, 6, 6) with ``W Σ Wᵀ = I``: the inverse Cholesky factor of each pose's covariance."""
    return leg_whiteners(a, b, P, R, sig)


def _unpack(x: np.ndarray, fixed_offsets: np.ndarray, fit_offsets: bool):
    """(a (6, 3) mm, b (6, 3) mm, offsets (6,) mm, θ (q,)) of ``x``: views, the offsets
    ``fixed_offsets`` when not fitted, θ everything after the geometry."""
    lay = ParameterLayout.of_vector(x, fit_offsets)
    return lay.a(x), lay.b(x), lay.offsets(x, fixed_offsets), lay.effects(x)


def residual(x, P, R, rho, fixed_offsets, fit_offsets=None, basis=None):
    """Residual (M, 6) mm at parameters ``x``: geometric length − predicted length, where the
    prediction is ``reading + offset + basis @ θ`` (θ the effect parameters); what
    :func:`_model` gives without its Jacobian (which is p times larger)."""
    return _legs(x, P, R, rho, fixed_offsets, fit_offsets, basis)[0]


def _legs(x, P, R, rho, fixed_offsets, fit_offsets, basis):
    """(residual (M, 6) mm, unit leg vectors (M, 6, 3), fit_offsets) at ``x``."""
    if fit_offsets is None:
        fit_offsets = len(x) > ParameterLayout(False).size
    a, b, off, theta = _unpack(x, fixed_offsets, fit_offsets)
    v = P[:, None, :] + np.einsum("mij,kj->mki", R, b) - a[None]
    length = np.linalg.norm(v, axis=-1)
    n = v / length[..., None]
    res = length - rho - off
    if basis is not None and basis.shape[-1]:
        res = res - basis @ theta
    return res, n, fit_offsets


def _model(x, P, R, rho, fixed_offsets, fit_offsets=None, basis=None):
    """Residual (M, 6) and raw Jacobian (M, 6, p): geometric length − predicted length, where the
    prediction is ``reading + offset + basis @ θ`` (θ the effect parameters)."""
    res, n, fit_offsets = _legs(x, P, R, rho, fixed_offsets, fit_offsets, basis)
    lay = ParameterLayout.of_vector(x, fit_offsets)
    m = len(P)
    jac = np.zeros((m, 6, len(x)))
    legs = np.arange(6)
    for c in range(3):
        jac[:, legs, lay.a_column(legs, c)] = -n[:, :, c]
    jac[:, legs, lay.b_column(legs, 0)] = 0.0
    rtn = np.einsum("mji,mkj->mki", R, n)  # Rᵀ n: d|v|/db
    for c in range(3):
        jac[:, legs, lay.b_column(legs, c)] = rtn[:, :, c]
    if fit_offsets:
        jac[:, legs, lay.offset_column(legs)] = -1.0
    if basis is not None and basis.shape[-1]:
        jac[:, :, lay.effects_slice] = -basis
    return res, jac


def refine(
    P: np.ndarray,
    R: np.ndarray,
    rho: np.ndarray,
    a0: np.ndarray,
    b0: np.ndarray,
    offsets0: np.ndarray,
    fit_offsets: bool,
    sigmas: NoiseSigmas | None = None,
    basis: np.ndarray | None = None,
    basis_names: list[str] | None = None,
    theta0: np.ndarray | None = None,
    passes: int = 2,
    clamps: ClampSteps | None = None,
) -> Refinement:
    """Weighted nonlinear least squares of the geometry, seeded by (a0, b0, offsets0).

    P (M, 3) mm, R (M, 3, 3), rho (M, 6) mm readings; a0, b0 (6, 3) mm; offsets0 (6,) mm (kept
    fixed unless ``fit_offsets``). ``sigmas`` are the instruments' noise; None means unknown.
    ``basis`` (M, 6, q) adds effect parameters θ (named ``basis_names``, seeded by ``theta0`` or
    zeros) with predicted length ``reading + offset + basis @ θ``. ``passes`` re-evaluations of
    the pose covariances (the second at the first pass's solution). ``clamps`` adds each clamped
    step's own constraint (:mod:`hexcal.estimate.clamp_rows`); its nuisance unknowns are eliminated from
    the reported parameters and covariance.
    """
    if clamps is not None and len(clamps):
        return _refine_with_clamps(
            P,
            R,
            rho,
            a0,
            b0,
            offsets0,
            fit_offsets,
            sigmas,
            basis,
            basis_names,
            theta0,
            passes,
            clamps,
        )
    known = sigmas is not None
    sig = sigmas if sigmas is not None else DEFAULT_SIGMAS
    fixed = np.asarray(offsets0, float)
    q = 0 if basis is None else basis.shape[-1]
    th = np.zeros(q) if theta0 is None else np.asarray(theta0, float)
    lay = ParameterLayout(fit_offsets, q)
    x = lay.pack(a0, b0, fixed, th)
    d = LegData.of(P, R, rho, fixed, basis if q else None)
    nfev = 0
    W = S = np.zeros((1, 0, 6, 6))
    for _ in range(passes):
        W, S = pose_precisions(x[None], d, lay, sig)
        sol = minimise(partial(_legs_at, d=d, S=S, lay=lay), x[None], MAX_NFEV)
        _check(sol, d, lay, "")
        x, nfev = sol.x[0], nfev + int(sol.nfev[0])
    res = leg_residuals(x[None], d, lay)[0]
    wres = (W[0] @ res[..., None])[..., 0]
    names = lay.names(basis_names)
    chi2 = float(np.sum(wres**2))
    out = _statistics(x, res, sol.system.A[0], chi2, 6 * len(P), known, names, nfev, True)
    out.whiteners = W[0]

    def whiten(x=x, W=W[0], res=res) -> tuple[np.ndarray, np.ndarray]:
        _, j = _model(x, P, R, rho, fixed, fit_offsets, basis if q else None)
        return (W @ j).reshape(-1, len(x)), (W @ res[..., None]).ravel()

    out._whiten = whiten
    return out


def _legs_at(x: np.ndarray, i: np.ndarray, d: LegData, S: np.ndarray, lay) -> Normal:
    """The leg rows' normal equations of the problems ``i`` of a batch at their x."""
    if len(i) == S.shape[0]:  # the whole batch, in order (minimise never reorders)
        return leg_normal(x, d, S, lay)
    return leg_normal(x, d.take_batch(i), S[i], lay)


def _check(sol, d: LegData, lay: ParameterLayout, what: str) -> None:
    """Raise :class:`FitStalled` unless the fit converged; a residual that is not finite at
    the start (a geometry that puts a leg at zero length, a non-finite input) is said so."""
    if not sol.finite[0]:
        raise FitStalled(
            [],
            "the fit cannot start: the residual is not finite at the starting geometry (a "
            "non-finite value in the table, or a leg of zero length)",
        )
    if not sol.converged[0]:
        raise _stalled(sol.x[0], d, lay, f"no convergence in {int(sol.nfev[0])} evaluations{what}")


def _refine_with_clamps(
    P, R, rho, a0, b0, offsets0, fit_offsets, sigmas, basis, basis_names, theta0, passes, clamps
) -> Refinement:
    """:func:`refine` with the clamp rows: the same parameters, plus each step's nuisance."""
    known = sigmas is not None
    sig = sigmas if sigmas is not None else DEFAULT_SIGMAS
    fixed = np.asarray(offsets0, float)
    m = len(P)
    basis = np.zeros((m, 6, 0)) if basis is None else basis
    q = basis.shape[-1]
    th = np.zeros(q) if theta0 is None else np.asarray(theta0, float)
    lay = ParameterLayout(fit_offsets, q)
    x = lay.pack(a0, b0, fixed, th)
    p0 = lay.size  # the steps' nuisance unknowns follow
    nu = Nuisance.seed(clamps, lay.a(x), lay.b(x), P, R)
    nfev = 0
    for _ in range(passes):
        prob = ClampProblem(clamps, P, R, rho, fixed, fit_offsets, basis, nu, x, sig)
        sol = minimise(prob.normal, prob.xf0[None], MAX_NFEV)
        _check(sol, LegData.of(P, R, rho, fixed, basis), lay, " (with the clamp rows)")
        nfev += int(sol.nfev[0])
        xf = sol.x[0]
        x, nu = xf[:p0], prob.template.nuisance_values(xf)
    res = leg_residuals(x[None], LegData.of(P, R, rho, fixed, basis), lay)[0]
    names = lay.names(basis_names)
    full = _statistics(
        xf,
        res,
        sol.system.full(),
        prob.chi2(xf),
        prob.n_rows,
        known,
        names + clamps.nuisance_names,
        nfev,
        True,
    )
    # The marginal covariance of the parameters is their block of the full inverse: the
    # nuisance unknowns are eliminated (Schur complement), not held fixed.
    keep = set(names)
    full.strong_correlations = [
        c for c in full.strong_correlations if c[0] in keep and c[1] in keep
    ]
    out = Refinement(
        names=names,
        x=x,
        cov=full.cov[:p0, :p0],
        sigma=full.sigma[:p0],
        ci95=full.ci95[:p0],
        corr=full.corr[:p0, :p0],
        chi2=full.chi2,
        dof=full.dof,
        noise_scale=full.noise_scale,
        noise_source=full.noise_source,
        residuals=full.residuals,
        status=full.status[:p0],
        notes=full.notes,
        strong_correlations=full.strong_correlations,
        nfev=nfev,
        success=full.success,
    )
    out.clamp_nuisance = nu
    out.clamp_steps = clamps
    return out


def _statistics(x, res, jtj, chi2, n_rows, known, names, nfev, success) -> Refinement:
    """The fit's statistics from its normal matrix ``jtj`` (p, p) (the whitened Jacobian's
    JᵀJ), χ² and the rows in use; ``res`` (M, 6) mm geometric − predicted length."""
    p = len(x)
    dof = max(n_rows - p, 1)
    s2 = chi2 / dof
    scale2 = max(1.0, s2) if known else s2

    d = 1.0 / np.sqrt(np.maximum(np.diag(jtj), 1e-300))
    A = d[:, None] * jtj * d[None, :]
    lam, V = np.linalg.eigh(A)
    null = lam < NULL_TOL * lam.max()
    inv_lam = np.where(null, 0.0, 1.0 / np.where(null, 1.0, lam))
    a_inv = (V * inv_lam) @ V.T
    cov = d[:, None] * a_inv * d[None, :] * scale2
    sigma = np.sqrt(np.maximum(np.diag(cov), 0.0))
    status = ["ok"] * p
    notes: list[str] = []

    # Parameters in an undetermined direction: only combinations are known.
    for col in np.where(null)[0]:
        v = V[:, col]
        big = np.where(np.abs(v) > 0.2 * np.abs(v).max())[0]
        for i in big:
            status[i] = "undetermined"
            sigma[i] = np.inf
        notes.append(
            "not determined by these data, only a combination of: "
            + ", ".join(names[i] for i in big)
        )

    sd = np.where(np.isfinite(sigma) & (sigma > 0), sigma, 1.0)
    corr = cov / sd[:, None] / sd[None, :]
    np.fill_diagonal(corr, 1.0)
    vif = np.diag(a_inv)
    for i in np.where((vif > VIF_LIMIT) & (np.array(status) == "ok"))[0]:
        status[i] = "not separable"
        partners = [j for j in np.argsort(-np.abs(corr[i])) if j != i][:2]
        notes.append(
            f"{names[i]} is not separable from "
            + " and ".join(f"{names[j]} (correlation {corr[i, j]:+.3f})" for j in partners)
            + f": its uncertainty is {np.sqrt(vif[i]):.0f}× what it would be alone; add poses "
            "that change the legs' directions more"
        )

    q = norm_ppf(0.975) if known else t_ppf(0.975, dof)
    iu = np.triu_indices(p, 1)
    order = np.argsort(-np.abs(corr[iu]))
    strong = [
        (names[iu[0][o]], names[iu[1][o]], float(corr[iu][o]))
        for o in order[:10]
        if abs(corr[iu][o]) > 0.9
    ]
    return Refinement(
        names=names,
        x=x,
        cov=cov,
        sigma=sigma,
        ci95=q * sigma,
        corr=corr,
        chi2=chi2,
        dof=dof,
        noise_scale=float(np.sqrt(s2)),
        noise_source="instruments" if known else "estimated from the residual",
        residuals=-res,
        status=status,
        notes=notes,
        strong_correlations=strong,
        nfev=nfev,
        success=success,
    )
