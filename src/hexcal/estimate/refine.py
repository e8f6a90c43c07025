"""Statistical refinement of the geometry over every recorded pose and all six legs.

``scipy.optimize.least_squares`` minimises the leg-length residual ``|P + R b_k − a_k| − ρ_k −
Δρ_k`` whitened by each pose's full 6×6 covariance (the six legs share the pose's tracker
noise; see :mod:`hexcal.model.noise`). The covariance depends on the geometry, so it is evaluated at
the linear seed, the fit is run, and it is re-evaluated at the solution for a second fit.

The parameter covariance is ``(JᵀJ)⁻¹`` of the whitened Jacobian. With the instruments' noise
stated, it is scaled by ``max(1, χ²/dof)`` (an under-fitting model widens the intervals, never
narrows them); without it, the noise level is estimated from the residual and the covariance
scaled by ``χ²/dof``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from hexcal.errors import RefusedError
from hexcal.estimate.clamp_rows import ClampModel, ClampSteps, Nuisance
from hexcal.estimate.layout import ParameterLayout
from hexcal.estimate.quantiles import norm_ppf, t_ppf
from hexcal.model.noise import DEFAULT_SIGMAS, NoiseSigmas, leg_covariance

#: Function evaluations one least-squares pass may take (a converging fit takes about 10): a
#: fit that needs more is pulled somewhere by poses that do not belong (:class:`FitStalled`).
MAX_NFEV = 200


class FitStalled(RefusedError, ValueError):
    """The refinement did not converge within :data:`MAX_NFEV` evaluations, or its residual is
    not finite. ``rows`` (0-based) are the poses with the largest whitened residual there: the
    ones pulling the fit."""

    def __init__(self, rows: list[int], why: str):
        self.rows = rows
        super().__init__(why)


def _stalled(x, P, R, rho, fixed, fit_offsets, basis, what: str) -> FitStalled:
    """The stall, naming the rows with the largest residual at ``x`` (the geometry part)."""
    with np.errstate(all="ignore"):
        res, _ = _model(x, P, R, rho, fixed, fit_offsets, basis)
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
    #: With clamp rows (``refine(clamps=...)``): the steps and their fitted nuisance values;
    #: the whitened arrays above are then left None (their rows are not the six leg lengths).
    clamp_steps: ClampSteps | None = None
    clamp_nuisance: Nuisance | None = None

    def value(self, name: str) -> float:
        return float(self.x[self.names.index(name)])

    def whitened(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(whitened Jacobian (6M, p), whitened residual (6M,), whiteners (M, 6, 6)) at the
        solution. A refinement with clamp rows has none: asking for them is a bug."""
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
    chol = np.linalg.cholesky(leg_covariance(a, b, P, R, sig))
    return np.linalg.inv(chol)


def _unpack(x: np.ndarray, fixed_offsets: np.ndarray, fit_offsets: bool):
    """(a (6, 3) mm, b (6, 3) mm, offsets (6,) mm, θ (q,)) of ``x``: views, the offsets
    ``fixed_offsets`` when not fitted, θ everything after the geometry."""
    lay = ParameterLayout.of_vector(x, fit_offsets)
    return lay.a(x), lay.b(x), lay.offsets(x, fixed_offsets), lay.effects(x)


def _model(x, P, R, rho, fixed_offsets, fit_offsets=None, basis=None):
    """Residual (M, 6) and raw Jacobian (M, 6, p): geometric length − predicted length, where the
    prediction is ``reading + offset + basis @ θ`` (θ the effect parameters)."""
    if fit_offsets is None:
        fit_offsets = len(x) > ParameterLayout(False).size
    lay = ParameterLayout.of_vector(x, fit_offsets)
    a, b, off, theta = _unpack(x, fixed_offsets, fit_offsets)
    v = P[:, None, :] + np.einsum("mij,kj->mki", R, b) - a[None]
    length = np.linalg.norm(v, axis=-1)
    n = v / length[..., None]
    res = length - rho - off
    if basis is not None and basis.shape[-1]:
        res = res - basis @ theta
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
    x = ParameterLayout(fit_offsets, q).pack(a0, b0, fixed, th)
    nfev = 0
    for _ in range(passes):
        a, b, _off, _ = _unpack(x, fixed, fit_offsets)
        W = _whiteners(a, b, P, R, sig)

        def fun(xx, W=W):
            res, _ = _model(xx, P, R, rho, fixed, fit_offsets, basis)
            return (W @ res[..., None]).ravel()

        def jac(xx, W=W):
            _, j = _model(xx, P, R, rho, fixed, fit_offsets, basis)
            return (W @ j).reshape(-1, len(xx))

        sol = _solve(fun, x, jac)
        if sol.status == 0 or not np.all(np.isfinite(sol.fun)):
            raise _stalled(
                sol.x,
                P,
                R,
                rho,
                fixed,
                fit_offsets,
                basis,
                f"no convergence in {sol.nfev} evaluations",
            )
        x, nfev = sol.x, nfev + sol.nfev
    res, _ = _model(x, P, R, rho, fixed, fit_offsets, basis)
    jw = jac(x)
    names = ParameterLayout(fit_offsets, q).names(basis_names)
    out = _statistics(x, res, jw, sol.fun, known, names, nfev, bool(sol.success))
    out.whitened_jacobian = jw
    out.whitened_residual = sol.fun
    out.whiteners = W
    return out


def _solve(fun, x0, jac):
    """One least-squares pass; a residual that is not finite at the start (a geometry that puts
    a leg at zero length, a non-finite input) is reported as a stalled fit, not as scipy's own
    message."""
    try:
        return least_squares(
            fun,
            x0,
            jac=jac,
            method="lm",
            xtol=1e-12,
            ftol=1e-12,
            gtol=1e-12,
            x_scale="jac",
            max_nfev=MAX_NFEV,
        )
    except ValueError:  # scipy: "Residuals are not finite in the initial point"
        raise FitStalled(
            [],
            "the fit cannot start: the residual is not finite at the starting geometry (a "
            "non-finite value in the table, or a leg of zero length)",
        ) from None


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
        model = ClampModel(clamps, P, R, rho, fixed, fit_offsets, basis, nu.u)
        xf = np.concatenate([x, model.nuisance_vector(nu)])
        W = model.whiteners(xf, sig.position_mm, sig.orientation_rad, sig.reading_mm)
        mask = model.mask

        def fun(xx, W=W, model=model, mask=mask):
            res, _, _ = model.evaluate(xx, want_jac=False, want_jz=False)
            return (W @ res[..., None])[..., 0][mask]

        def jac(xx, W=W, model=model, mask=mask):
            _, j, _ = model.evaluate(xx, want_jz=False)
            return (W @ j)[mask]

        sol = _solve(fun, xf, jac)
        if sol.status == 0 or not np.all(np.isfinite(sol.fun)):
            raise _stalled(
                sol.x[:p0],
                P,
                R,
                rho,
                fixed,
                fit_offsets,
                basis if q else None,
                f"no convergence in {sol.nfev} evaluations (with the clamp rows)",
            )
        nfev += sol.nfev
        x, nu = sol.x[:p0], model.nuisance_values(sol.x)
    res, _ = _model(x, P, R, rho, fixed, fit_offsets, basis if q else None)
    jw = jac(sol.x)
    names = ParameterLayout(fit_offsets, q).names(basis_names)
    full = _statistics(
        sol.x, res, jw, sol.fun, known, names + clamps.nuisance_names, nfev, bool(sol.success)
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


def _statistics(x, res, jw, wres, known, names, nfev, success) -> Refinement:
    p = len(x)
    chi2 = float(wres @ wres)
    dof = max(jw.shape[0] - p, 1)
    s2 = chi2 / dof
    scale2 = max(1.0, s2) if known else s2

    jtj = jw.T @ jw
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
