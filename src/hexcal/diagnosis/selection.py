"""Model selection in one place: how two or more fitted (or planned) hypotheses compare.

The verdict (:mod:`hexcal.diagnosis.verdict`), the planner (:mod:`hexcal.diagnosis.plan`) and
the live ranking (:mod:`hexcal.diagnosis.live_rank`) all weigh hypotheses here:

- fitted models: ΔBIC (:func:`bic_delta`), the held-out gain (:func:`heldout_gain`), Vuong's
  test of two non-nested fits on the same poses (:func:`vuong_z`), whether a candidate may be
  named (:func:`wins`) and which others fit alike (:func:`alike`);
- hypotheses on poses not yet recorded: the expected separation, the noncentrality of one
  hypothesis' fitted contribution once the other's model is projected out, from normal
  equations (Gram matrices: :func:`schur_last`, and after each candidate pose at once,
  :func:`schur_after`), and the Δχ² the poses are expected to show, its mean and spread given
  the poses recorded (:func:`predicted_delta_chi2`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from hexcal.diagnosis.scoring import Candidate
from hexcal.estimate.effect_fit import ModelFit, Problem

#: ΔBIC below which an effect's evidence is "very strong" (Kass & Raftery).
BIC_STRONG = -10.0
#: An effect that brings the residual to the floor (alone or with one more) must explain at
#: least this share of the excess over the noise floor.
MOST = 0.5
#: An effect that does not, while other catalogue effects explain the rest, must explain at
#: least this share: with three effects hidden the first named explains 60–100 % of the excess,
#: a look-alike of a structured residual outside the catalogue a few per cent.
CLEAR = 0.25
#: An effect predicts held-out poses better when the mean per-pose gain in held-out χ² is this
#: many standard errors above 0 (one-sided p 0.023 per candidate for a normal mean; stricter in
#: fact: adding parameters costs held-out accuracy, so an effect that only fits noise scores
#: below 0 on average). Thermal expansion hidden at its realistic size, at the floor, scores
#: 2.5–6.4 over 40 simulated sessions; clean sessions' candidates stay below it.
HELDOUT_Z = 2.0
#: Two refitted effects fit alike when their χ² (over the noise level) differ by less than this:
#: a likelihood ratio below e⁵ ≈ 150, short of "very strong" evidence for either.
ALIKE_DCHI2 = 10.0


def bic_delta(problem: Problem, base: ModelFit, new: ModelFit) -> float:
    """ΔBIC of ``new`` against ``base`` (χ² with the stated noise, else the Gaussian
    likelihood with the level estimated)."""
    n = base.refinement.dof + len(base.refinement.x)  # the residual rows
    dp = new.n_params - base.n_params
    if problem.sigmas is not None:
        return bic_from_chi2(new.chi2 - base.chi2, dp, n)
    return n * np.log(new.chi2 / base.chi2) + dp * np.log(n)


def bic_from_chi2(dchi2: float, dp: int, n: int) -> float:
    """ΔBIC of a model ``dp`` parameters larger whose χ² (with the stated noise) changes by
    ``dchi2``, over ``n`` residual rows."""
    return float(dchi2 + dp * np.log(n))


def wins(c: Candidate, excess: bool) -> bool:
    """Whether ``c`` may be named (the rules of :mod:`hexcal.diagnosis.verdict`'s docstring)."""
    if c.refit is None or not c.delta_bic < BIC_STRONG:
        return False
    if not excess:
        return c.heldout_z > HELDOUT_Z
    if c.explained >= MOST and c.closes:
        return True
    return c.explained >= CLEAR and c.heldout_z > HELDOUT_Z and c.chain


def alike(
    whiteners: Callable[[], np.ndarray],
    best: Candidate,
    candidates: list[Candidate],
    s2: float,
) -> list[str]:
    """The other refitted candidates with very strong evidence that the data cannot tell from
    ``best`` (:func:`indistinct`): unless each fits worse than ``best`` by both χ² (over the
    noise level, :data:`ALIKE_DCHI2`) and the poses' χ² beyond their noise (Vuong's test,
    :func:`vuong_z`, :data:`HELDOUT_Z`) — a ΔBIC margin inside the noise of the poses is no
    evidence, and one that fits better while the parameter count alone ranks it behind is
    not beaten. Two that both bring the residual to the floor are named together unless the
    poses decide between them that way. ``whiteners`` gives the poses' (M, 6, 6) whiteners
    when a Vuong test is needed."""
    if best.refit is None:
        return []
    chol = None
    out = []
    for c in candidates:
        if c is best or c.refit is None or not c.delta_bic < BIC_STRONG:
            continue
        dchi2 = (c.refit.chi2 - best.refit.chi2) / s2
        z = 0.0
        if dchi2 >= ALIKE_DCHI2:  # a Vuong test only where χ² alone does not say alike
            chol = whiteners() if chol is None else chol
            z = vuong_z(c.refit, best.refit, chol, s2)
        if indistinct(dchi2, z):
            out.append(c.effect)
    return out


def indistinct(dchi2: float, z: float) -> bool:
    """Whether a fit ranked behind the best one (by ΔBIC) is its look-alike, from the excess of
    its χ² over the best's (over the noise level) ``dchi2`` and Vuong's z of the two (its
    poses' χ² less the best's, :func:`vuong_z`): unless it fits worse by at least
    :data:`ALIKE_DCHI2` and by :data:`HELDOUT_Z` standard errors of the poses' χ². The rule
    :func:`alike` applies and the planner's benchmark judges its sessions by."""
    return dchi2 < ALIKE_DCHI2 or z < HELDOUT_Z


def separates(mean: float, sd: float, dp: int, n: int, nested: bool) -> bool:
    """Whether an expected separation decides for the true hypothesis by the verdict's rules,
    two standard deviations short of its mean: the Δχ² the other leaves beyond it — its mean
    ``mean`` (:func:`predicted_delta_chi2`), standard deviation ``sd`` — must pay for ``dp``,
    the true one's parameters less the other's, in ΔBIC over ``n`` residual rows and pass the
    look-alike margin (:data:`ALIKE_DCHI2`; Vuong's z ≥ 2 asks about the same of a Δχ² whose
    spread is ``sd``); against the model alone (``nested``) the effect's ΔBIC must be very
    strong (:data:`BIC_STRONG`)."""
    cost = dp * float(np.log(n))
    margin = cost - BIC_STRONG if nested else max(ALIKE_DCHI2, cost)
    return bool(mean - 2.0 * sd >= margin)


def vuong_z(a: ModelFit, b: ModelFit, chol: np.ndarray, s2: float = 1.0) -> float:
    """Vuong's z of two fitted models on the same poses: the mean per-pose difference of their
    χ² (``a``'s less ``b``'s, each pose's residuals whitened by its 6×6 covariance) over its
    standard error. |z| < 2: the data do not prefer either (a difference of ΔBIC that size is
    inside the noise of the poses, whatever the parameter counts)."""
    d = _pose_chi2(a.residuals, chol, s2) - _pose_chi2(b.residuals, chol, s2)
    sd = float(np.std(d, ddof=1))
    return float(np.mean(d) / sd * np.sqrt(len(d))) if sd > 0 else 0.0


def _pose_chi2(h: np.ndarray, chol: np.ndarray, s2: float) -> np.ndarray:
    w = np.linalg.solve(chol, h[..., None])[..., 0]
    return np.sum(w**2, axis=1) / s2


def heldout_gain(
    before: ModelFit, after: ModelFit, chol: np.ndarray, s2: float = 1.0
) -> tuple[float, float]:
    """(Δχ², z): how much better ``after`` predicts the poses it was not fitted to than
    ``before`` does, each pose's held-out residuals (random folds) whitened by its 6×6
    covariance (``chol``: :func:`pose_whiteners`) over the noise level ``s2``; z is the mean
    per-pose gain over its standard error (a paired test over poses)."""

    def chi(h: np.ndarray) -> np.ndarray:
        w = np.linalg.solve(chol, h[..., None])[..., 0]
        return np.sum(w**2, axis=1) / s2

    d = chi(before.held_out_residuals) - chi(after.held_out_residuals)
    sd = float(np.std(d, ddof=1))
    z = float(np.mean(d) / sd * np.sqrt(len(d))) if sd > 0 else 0.0
    return float(d.sum()), z


def fit_apart(a: ModelFit, b: ModelFit, chol: np.ndarray, s2: float = 1.0) -> bool:
    """Whether two fits of the same poses fit differently, not one model written twice: the
    χ² of their residuals' difference (each pose's whitened by ``chol``, over ``s2``) beyond
    :data:`ALIKE_DCHI2` plus their parameter counts' difference (what the larger takes up of
    the noise alone). The catalogue's backlash and a step at the sign of each leg's last move
    fit to 0.0 of each other, its compliance and a line in the force shared by the legs to
    0.2, its lead screw and a cycle of 4.99 mm to 5, a curve in time and the same curve in
    the pose's rank (r 1.000) to < 1; a cross-talk and gain differ by 47–81. Two fits that
    are not apart can still differ in held-out figures beyond 2 standard errors, by the
    folds' one-step refits alone (8 of some 400 simulated sessions): such a difference is
    not evidence for either."""
    d = a.residuals - b.residuals
    w = np.linalg.solve(chol, d[..., None])[..., 0]
    return bool(np.sum(w**2) / s2 > ALIKE_DCHI2 + abs(a.n_params - b.n_params))


def schur_last(gram: np.ndarray) -> np.ndarray:
    """(...,) the Schur complement of the last diagonal element of Gram matrices (..., p+1,
    p+1) ``[[JᵀJ, Jᵀd], [dᵀJ, dᵀd]]``: ``|d⊥|²``, what is left of the column d once the
    columns J are projected out (the pseudo-inverse on J's span: a column J does not
    determine, the geometry's gauge, is not in it)."""
    jj = gram[..., :-1, :-1]
    jd = gram[..., :-1, -1]
    dd = gram[..., -1, -1]
    scale = np.sqrt(np.clip(np.einsum("...ii->...i", jj), 1e-300, None))
    jj_s = jj / scale[..., :, None] / scale[..., None, :]
    inv = np.linalg.pinv(jj_s, rcond=1e-12, hermitian=True)
    jd_s = jd / scale
    return np.clip(dd - np.einsum("...i,...ij,...j->...", jd_s, inv, jd_s), 0.0, None)


def schur_block(gram: np.ndarray, q: int) -> np.ndarray:
    """(..., q, q) the information of the last ``q`` columns of Gram matrices (..., p, p) once
    the others are projected out (the Schur complement of the leading block)."""
    aa, ab, bb = gram[..., :-q, :-q], gram[..., :-q, -q:], gram[..., -q:, -q:]
    scale = np.sqrt(np.clip(np.einsum("...ii->...i", aa), 1e-300, None))
    inv = np.linalg.pinv(
        aa / scale[..., :, None] / scale[..., None, :], rcond=1e-12, hermitian=True
    )
    ab_s = ab / scale[..., :, None]
    return bb - np.swapaxes(ab_s, -1, -2) @ inv @ ab_s


def schur_after(gram: np.ndarray, rows: np.ndarray, q: int) -> np.ndarray:
    """(K, q, q): the information of the last ``q`` columns, the others projected out, once
    each of K candidate poses' rows (K, r, p) is added to the Gram matrix ``gram`` (p, p) —
    every candidate at once, by the Woodbury identity (an r × r solve per candidate, no p × p
    one). With q = 1 and a hypothesis' fitted contribution as the last column, the result is
    the separation's noncentrality after that pose (:func:`schur_last`)."""
    m = gram.shape[0] - q
    s = np.sqrt(np.clip(np.diag(gram)[:m], 1e-300, None))
    a_inv = np.linalg.pinv(gram[:m, :m] / np.outer(s, s), rcond=1e-12, hermitian=True)
    c = gram[:m, m:] / s[:, None]
    u = rows[..., :m] / s
    v = rows[..., m:]
    y = c + np.swapaxes(u, -1, -2) @ v  # (K, m, q)
    z = a_inv @ y
    ua = u @ a_inv  # (K, r, m)
    inner = np.eye(u.shape[-2]) + ua @ np.swapaxes(u, -1, -2)
    uz = u @ z  # (K, r, q)
    out = gram[m:, m:] + np.swapaxes(v, -1, -2) @ v - np.swapaxes(y, -1, -2) @ z
    return out + np.swapaxes(uz, -1, -2) @ np.linalg.solve(inner, uz)


def predicted_delta_chi2(
    true_cols: np.ndarray,
    other_cols: np.ndarray,
    residual: np.ndarray,
    noise_only: bool = False,
) -> tuple[float, float]:
    """(mean, standard deviation) of Δχ² = χ²_other − χ²_true, both models refitted on every
    row, before the rows after the first ``len(residual)`` (the new poses') are recorded,
    given those first rows' whitened residuals ``residual`` (at a fit both models extend;
    unit noise), the true model's columns ``true_cols`` (N, pA) and the other's
    ``other_cols`` (N, pB) over all N rows (the common ones in both).

    Linear and Gaussian, Δχ² = yᵀQy, Q = P_A − P_B the difference of the two projections, y
    every row's residuals. The prediction is ŷᵀQŷ, ŷ the first rows' residuals followed by
    what the true model fitted to them predicts for the new rows, plus the mean of the
    realised less it over the noise of every row (the session's too: the fit ŷ is made of it)
    — the truth μ fixed, whatever it is: with e the noise and T the map that makes ŷ − μ of it
    (the first rows' noise, and the fit's error seen through the new rows' columns), the
    difference is 2μᵀQ(I − T)e + eᵀMe, M = Q − TᵀQT. So

    - mean = ŷᵀQŷ + tr M (unbiased: a fit's θ̂ is longer than θ on average, and a plug-in
      ŷᵀQŷ alone overstates a poorly resolved effect's separation many times over);
    - variance = 4 |(I − T)ᵀQμ|² + 2 tr M², the first term estimated without bias from ŷ
      (its excess over μ's, ‖(I − T)ᵀQT‖², taken off).

    ``noise_only``: the standard deviation over the new rows' noise alone, the first rows
    held as recorded (what redrawing only the new poses' noise spreads the Δχ² by):
    4 |(Qμ)_n|² + 2 tr Q_nn², estimated alike. Reckoned on the models' thin bases (no N × N
    matrix)."""
    m = len(residual)
    ua, ub = _basis(true_cols), _basis(other_cols)
    u = np.concatenate([ua, ub], axis=1)
    j = np.concatenate([np.ones(ua.shape[1]), -np.ones(ub.shape[1])])
    scale = np.sqrt(np.clip(np.sum(true_cols[:m] ** 2, axis=0), 1e-300, None))
    zs, zn = true_cols[:m] / scale, true_cols[m:] / scale
    cov = np.linalg.pinv(zs.T @ zs, rcond=1e-12, hermitian=True)
    y = np.concatenate([residual, zn @ (cov @ (zs.T @ residual))])
    qy = u @ (j * (u.T @ y))
    # TᵀU: the first rows' U_s + Z_s C Z_nᵀ U_n, none on the new rows
    w = u[:m] + zs @ (cov @ (zn.T @ u[m:]))
    uu, ww, uw = u.T @ u, w.T @ w, u[:m].T @ w
    un = u[m:].T @ u[m:]
    a = qy[m:]
    if noise_only:
        jq = j[:, None] * un
        bias = float(np.sum((j[:, None] * ww * j[None, :]) * un.T))
        var = 4.0 * max(float(a @ a) - bias, 0.0) + 2.0 * float(np.sum(jq * jq.T))
        return float(y @ qy + np.trace(j[:, None] * uu) - np.trace(j[:, None] * ww)), float(
            np.sqrt(var)
        )
    ev, evec = np.linalg.eigh(cov)
    lo = zn @ (evec * np.sqrt(np.clip(ev, 0.0, None)))  # Z_n C Z_nᵀ = lo loᵀ
    lu = lo.T @ u[m:]
    unv = un + lu.T @ lu  # U_nᵀ V U_n, V = I + Z_n C Z_nᵀ
    tr_m = float(np.sum(j * np.diag(uu)) - np.sum(j * np.diag(ww)))
    ju, jw, jx = j[:, None] * uu, j[:, None] * ww, j[:, None] * uw
    tr_m2 = float(np.sum(ju * ju.T) - 2.0 * np.sum(jx * (j[:, None] * uw.T).T) + np.sum(jw * jw.T))
    lin = float(a @ a) + float(np.sum((lo.T @ a) ** 2))
    bias = float(np.sum((j[:, None] * ww * j[None, :]) * unv.T))
    var = 4.0 * max(lin - bias, 0.0) + 2.0 * max(tr_m2, 0.0)
    return float(y @ qy) + tr_m, float(np.sqrt(var))


def _basis(cols: np.ndarray) -> np.ndarray:
    """(N, r) an orthonormal basis of the columns' span (scaled to unit norm first; a
    direction below 1e-10 of the largest singular value is no part of it)."""
    s = np.sqrt(np.clip(np.sum(cols**2, axis=0), 1e-300, None))
    u, sv, _ = np.linalg.svd(cols / s, full_matrices=False)
    return u[:, sv > 1e-10 * sv[0]] if len(sv) else u


#: Draws of the new poses from the predictive that :func:`predicted_vuong_z` takes.
VUONG_DRAWS = 64


def predicted_vuong_z(
    true_cols: np.ndarray, other_cols: np.ndarray, residual: np.ndarray, seed: int = 0
) -> float:
    """Vuong's z of the two models (:func:`vuong_z`: the other's per-pose χ² less the true
    one's, rows in poses of six) once the new rows are recorded, two standard deviations
    short: its 2.3 % quantile over :data:`VUONG_DRAWS` draws of the new rows' residuals from
    the predictive of :func:`predicted_delta_chi2` (the true model fitted to the first rows,
    that fit's spread, unit noise), both models refitted (projected) on every row each time.
    A separation carried by k poses has a z of at most about √k however large its Δχ²: few
    poses decide by Δχ² and still fit alike by Vuong's test."""
    m = len(residual)
    ua, ub = _basis(true_cols), _basis(other_cols)
    scale = np.sqrt(np.clip(np.sum(true_cols[:m] ** 2, axis=0), 1e-300, None))
    zs, zn = true_cols[:m] / scale, true_cols[m:] / scale
    cov = np.linalg.pinv(zs.T @ zs, rcond=1e-12, hermitian=True)
    gamma = cov @ (zs.T @ residual)
    ev, evec = np.linalg.eigh(cov)
    spread = evec * np.sqrt(np.clip(ev, 0.0, None))
    rng = np.random.default_rng(seed)
    g = gamma + rng.normal(size=(VUONG_DRAWS, len(gamma))) @ spread.T
    new = g @ zn.T + rng.normal(size=(VUONG_DRAWS, len(zn)))
    y = np.concatenate([np.broadcast_to(residual, (VUONG_DRAWS, m)), new], axis=1)
    ra = y - (y @ ua) @ ua.T
    rb = y - (y @ ub) @ ub.T
    d = (rb**2 - ra**2).reshape(VUONG_DRAWS, -1, 6).sum(axis=-1)
    sd = d.std(axis=1, ddof=1)
    z = np.where(sd > 0, d.mean(axis=1) / np.where(sd > 0, sd, 1.0) * np.sqrt(d.shape[1]), 0.0)
    return float(np.quantile(z, 0.023))
