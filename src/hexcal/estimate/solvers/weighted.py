"""Weighted refinement of one leg's clamp constraint, batched over trials (used by the study).

Each pose's constraint residual is weighted by its own covariance, propagated from the tracker
and encoder noise, and the unit-direction / radius unknowns are fitted exactly:

* Type I: ``e_i = P_i + R_i b − a − ρ_i u`` (3 per pose), u a unit vector;
* Type II: ``e_i = P_i + R_i b − C`` (3 per pose);
* Type III: ``e_i = |P_i + R_i b − a| − r`` (1 per pose), b given.

A Gauss-Newton loop over a whole batch replaces a Python loop of ``least_squares`` calls (the
study fits a few hundred thousand of them); tests check it reaches the same optimum as
``scipy.optimize.least_squares`` on single problems.
"""

from __future__ import annotations

import numpy as np

from hexcal.model.noise import NoiseSigmas


def _inv3_sym(s: np.ndarray) -> np.ndarray:
    """Inverse of symmetric 3×3 matrices (..., 3, 3) by cofactors: elementwise, so a batch of a
    million is one vectorised expression rather than a million LAPACK calls."""
    a, b, c = s[..., 0, 0], s[..., 0, 1], s[..., 0, 2]
    d, e, f = s[..., 1, 1], s[..., 1, 2], s[..., 2, 2]
    c00, c01, c02 = d * f - e * e, c * e - b * f, b * e - c * d
    c11, c12, c22 = a * f - c * c, b * c - a * e, a * d - b * b
    det = a * c00 + b * c01 + c * c02
    out = np.stack([c00, c01, c02, c01, c11, c12, c02, c12, c22], axis=-1) / det[..., None]
    return out.reshape(s.shape)


def _outer(u: np.ndarray) -> np.ndarray:
    return u[..., :, None] * u[..., None, :]


def _rotated(R: np.ndarray, b: np.ndarray) -> np.ndarray:
    """R_i b (..., N, 3) for R (..., N, 3, 3) and b (..., 3): one einsum, twice as fast as a
    stack of matrix-vector products."""
    return np.einsum("...nij,...j->...ni", R, b)


def _point_cov(
    R: np.ndarray, b: np.ndarray, sig: NoiseSigmas, rb: np.ndarray | None = None
) -> np.ndarray:
    """Covariance (..., N, 3, 3) of the measured B_i = P_i + R_i b: position plus orientation
    (``rb``: R_i b when the caller has it).

    The orientation part is ``σθ² (R[b]x)(R[b]x)ᵀ = σθ² (|b|² I − (Rb)(Rb)ᵀ)``.
    """
    rb = _rotated(R, b) if rb is None else rb
    cov = rb[..., :, None] * (-(sig.orientation_rad**2) * rb[..., None, :])
    diag = sig.position_mm**2 + sig.orientation_rad**2 * np.sum(b * b, axis=-1)
    cov.reshape(*cov.shape[:-2], 9)[..., ::4] += diag[..., None, None]  # the diagonal, a view
    return cov


def _point_var(
    R: np.ndarray, b: np.ndarray, n: np.ndarray, sig: NoiseSigmas, rb: np.ndarray | None = None
) -> np.ndarray:
    """nᵀ Σ n (..., N) mm² for unit vectors n (..., N, 3), Σ the covariance of B_i
    (:func:`_point_cov`), without forming Σ: ``σp² + σθ² (|b|² − (n·R b)²)`` (``rb``: R_i b
    when the caller has it)."""
    nrb = np.einsum("...i,...i->...", n, _rotated(R, b) if rb is None else rb)
    b2 = np.sum(b * b, axis=-1)[..., None]
    return sig.position_mm**2 + sig.orientation_rad**2 * (b2 - nrb**2)


def _normal(jac: np.ndarray, w: np.ndarray, res: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normal equations (JᵀWJ (..., p, p), JᵀWr (..., p, 1)) summed over per-pose blocks: jac
    (..., N, q, p), weights w (..., N, q, q) = Σ⁻¹, residual res (..., N, q)."""
    # One row a pose (Type III): its weight is a scalar, a product not a 1×1 matrix product.
    wj = w * jac if w.shape[-1] == 1 else w @ jac
    shape = np.broadcast_shapes(jac.shape, wj.shape)
    jac, wj = np.broadcast_to(jac, shape), np.broadcast_to(wj, shape)
    # The poses' rows stacked, (..., N q, p): the sum over the poses is then one matrix product
    # per trial (BLAS), rather than N small products and a sum (4× slower).
    rows = (*shape[:-3], shape[-3] * shape[-2], shape[-1])
    jac_t = np.swapaxes(jac.reshape(rows), -1, -2)
    wj_t = np.swapaxes(wj.reshape(rows), -1, -2)
    return jac_t @ wj.reshape(rows), wj_t @ res.reshape(*rows[:-1], 1)


def _solve_step(jtj: np.ndarray, jtr: np.ndarray) -> np.ndarray:
    """The Gauss-Newton step (..., p) of the normal equations (a whisker of damping keeps a
    degenerate batch member from stopping the others)."""
    damp = 1e-12 * np.trace(jtj, axis1=-2, axis2=-1)[..., None, None] * np.eye(jtj.shape[-1])
    return -np.linalg.solve(jtj + damp, jtr)[..., 0]


def _gn_step(jac: np.ndarray, w: np.ndarray, res: np.ndarray) -> np.ndarray:
    """Gauss-Newton step (..., p) from per-pose blocks (see :func:`_normal`)."""
    return _solve_step(*_normal(jac, w, res))


def _tangent_basis(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (..., 3) orthogonal to u (..., 3) and to each other."""
    helper = np.where(np.abs(u[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    e1 = np.cross(u, helper)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    return e1, np.cross(u, e1)


def refine_type_i(P, R, length, b0, a0, u0, sig: NoiseSigmas, iterations: int = 2):
    """Weighted Type I fit: (b, a, u) each (..., 3), seeded by a linear solution."""
    b, a = b0.copy(), a0.copy()
    u = u0 / np.linalg.norm(u0, axis=-1, keepdims=True)
    # The Jacobian's R and −I blocks stay; only the direction's columns change.
    j = np.zeros((*R.shape[:-1], 8))
    j[..., :3] = R
    j[..., [0, 1, 2], [3, 4, 5]] = -1.0
    lt = -length[..., None]
    for _ in range(iterations):
        rb = _rotated(R, b)
        w = _inv3_sym(_point_cov(R, b, sig, rb) + sig.reading_mm**2 * _outer(u)[..., None, :, :])
        e1, e2 = _tangent_basis(u)
        res = P + rb - a[..., None, :] - length[..., None] * u[..., None, :]
        j[..., 6] = lt * e1[..., None, :]
        j[..., 7] = lt * e2[..., None, :]
        dx = _gn_step(j, w, res)
        b = b + dx[..., :3]
        a = a + dx[..., 3:6]
        u = u + dx[..., 6:7] * e1 + dx[..., 7:8] * e2
        u /= np.linalg.norm(u, axis=-1, keepdims=True)
    return b, a, u


def refine_type_i_nested(P, R, length, counts, b0, u0, sig: NoiseSigmas):
    """The weighted Type I fit of the first counts[c] poses of each set at once: (b, a, u)
    each (..., C, 3). P (..., n, 3) mm, R (..., n, 3, 3), length (..., n) mm, counts (C,)
    increasing; the weights are each pose's covariance at a pilot (b0, u0) (..., 3) that the
    caller takes from the first counts[0] poses, so that no count's fit sees a later pose.

    The residual ``P_i + R_i b − a − ρ_i u`` is linear in x = (b, a, u), so with the weights
    held the cost ``Σ rᵢᵀ Wᵢ rᵢ`` is a quadratic form whose sums over the poses cumulate: every
    count's form is read off one running sum, and minimised exactly on |u| = 1 (b and a
    eliminated, then the trust-region secular equation of the 3×3 form in u, solved by Newton
    on 1/|u(μ)|; Moré & Sorensen 1983). It is the fixed point of
    :func:`refine_type_i` but for the weights' point; a weight moves by about σ_u (mrad) from
    one to the other, which changes the estimate by less than a hundredth of its spread
    (tests/test_solvers_weighted.py)."""
    from hexcal.estimate.solvers.direct import type_i_system
    from hexcal.estimate.solvers.linalg import running_sums

    counts = np.asarray(counts, int)
    n = int(counts[-1])
    P, R, length = P[..., :n, :], R[..., :n, :, :], length[..., :n]
    u0 = u0 / np.linalg.norm(u0, axis=-1, keepdims=True)
    w = _inv3_sym(_point_cov(R, b0, sig) + sig.reading_mm**2 * _outer(u0)[..., None, :, :])
    m, y = type_i_system(P, R, length)  # (..., 3n, 9), (..., 3n)
    m = m.reshape(*P.shape[:-1], 3, 9)
    wm = w @ m  # (..., n, 3, 9)
    mt = np.swapaxes(m, -1, -2)
    A = running_sums(mt @ wm, counts, axis=-3)  # (..., C, 9, 9)
    g = running_sums((np.swapaxes(wm, -1, -2) @ y.reshape(*P.shape, 1))[..., 0], counts, axis=-2)
    # b and a eliminated: the form in u alone, uᵀ Q u − 2 qᵀ u.
    zz, zu, uu = A[..., :6, :6], A[..., :6, 6:], A[..., 6:, 6:]
    sol = np.linalg.solve(zz, np.concatenate([zu, g[..., :6, None]], axis=-1))
    Q = uu - np.swapaxes(zu, -1, -2) @ sol[..., :3]
    q = g[..., 6:] - (np.swapaxes(zu, -1, -2) @ sol[..., 3:])[..., 0]
    u = _on_unit_sphere(Q, q)
    z = sol[..., 3] - np.einsum("...ij,...j->...i", sol[..., :3], u)
    return z[..., :3], z[..., 3:6], u


#: Newton steps of :func:`_on_unit_sphere` at most (three or four on the study's sets).
NEWTON_STEPS = 40
#: How close to 1 :func:`_on_unit_sphere` brings |u|: rounding (the form's entries are
#: ρ² / σ², 1e7–1e9, so that u's last digits are noise at 1e-14).
UNIT = 1e-13


def _positive_definite(m: np.ndarray) -> np.ndarray:
    """Whether each symmetric 3×3 matrix of m (..., 3, 3) is positive definite (its leading
    minors, elementwise)."""
    a, b, d = m[..., 0, 0], m[..., 0, 1], m[..., 1, 1]
    return (a > 0) & (a * d - b * b > 0) & (np.linalg.det(m) > 0)


def _on_unit_sphere(Q: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The minimiser u (..., 3) of ``uᵀ Q u − 2 qᵀ u`` on |u| = 1, Q (..., 3, 3) positive
    definite: ``(Q + μ I) u = q`` with Q + μ I positive definite (Moré & Sorensen 1983).
    Newton on ψ(μ) = 1/|u(μ)|, concave and increasing, converges from below the root without
    passing it; a step from above that would leave Q + μ I indefinite is halved back. Only the
    members not yet at |u| = 1 (to :data:`UNIT`) are stepped."""
    shape = q.shape
    Q, q = Q.reshape(-1, 3, 3), q.reshape(-1, 3)
    eye = np.eye(3)
    mu = np.zeros(len(q))
    u = np.empty_like(q)
    todo = np.arange(len(q))
    for _ in range(NEWTON_STEPS):
        m, qt = Q[todo] + mu[todo, None, None] * eye, q[todo]
        inv = _inv3_sym(m)
        u[todo] = ut = np.einsum("...ij,...j->...i", inv, qt)
        un = np.sqrt(np.sum(ut * ut, axis=-1))
        going = np.abs(un - 1.0) > UNIT
        todo, ut, un, inv, m = todo[going], ut[going], un[going], inv[going], m[going]
        if not len(todo):
            break
        dun = -np.einsum("...i,...ij,...j->...", ut, inv, ut) / un  # d|u|/dμ
        step = -(un - 1.0) * un / dun  # Newton on ψ(μ) − 1
        for _half in range(60):
            bad = ~_positive_definite(m + step[..., None, None] * eye)
            if not bad.any():
                break
            step[bad] *= 0.5
        mu[todo] += step
    return u.reshape(shape)


def refine_type_ii(P, R, b0, c0, sig: NoiseSigmas, iterations: int = 1):
    """Weighted Type II fit: (b, C) each (..., 3). Linear once the weights are set from b."""
    b, c = b0.copy(), c0.copy()
    j = np.concatenate([R, -np.broadcast_to(np.eye(3), R.shape)], axis=-1)
    for _ in range(iterations):
        w = _inv3_sym(_point_cov(R, b, sig))
        res = P + _rotated(R, b) - c[..., None, :]
        dx = _gn_step(j, w, res)
        b, c = b + dx[..., :3], c + dx[..., 3:]
    return b, c


def refine_type_ii_nested(P, R, counts, b0, sig: NoiseSigmas):
    """The weighted Type II fit of the first counts[c] poses of each set at once: (b, C) each
    (..., C, 3). P (..., n, 3) mm, R (..., n, 3, 3), counts (C,) increasing; the weights are
    each pose's covariance at a pilot b0 (..., 3) that the caller takes from the first
    counts[0] poses. The residual ``P_i + R_i b − C`` is linear, so this is
    :func:`refine_type_ii` from the pilot for every count, its normal equations read off one
    running sum (as :func:`refine_type_i_nested`'s)."""
    from hexcal.estimate.solvers.direct import type_ii_system
    from hexcal.estimate.solvers.linalg import running_sums

    counts = np.asarray(counts, int)
    n = int(counts[-1])
    P, R = P[..., :n, :], R[..., :n, :, :]
    w = _inv3_sym(_point_cov(R, b0, sig))
    m, y = type_ii_system(P, R)  # (..., 3n, 6), (..., 3n)
    m = m.reshape(*P.shape[:-1], 3, 6)
    wm = w @ m  # (..., n, 3, 6)
    A = running_sums(np.swapaxes(m, -1, -2) @ wm, counts, axis=-3)  # (..., C, 6, 6)
    g = running_sums((np.swapaxes(wm, -1, -2) @ y.reshape(*P.shape, 1))[..., 0], counts, axis=-2)
    x = np.linalg.solve(A, g[..., None])[..., 0]
    return x[..., :3], x[..., 3:]


def refine_type_iii(P, R, b, a0, r0, sig: NoiseSigmas, iterations: int = 3):
    """Weighted Type III fit (sphere of unknown radius): (a (..., 3), r (...,)) given b."""
    a, r = a0.copy(), np.asarray(r0, float).copy()
    v = P + _rotated(R, b)
    for _ in range(iterations):
        d = v - a[..., None, :]
        dist = np.linalg.norm(d, axis=-1)
        n = d / dist[..., None]
        var = _point_var(R, b, n, sig)
        j = np.concatenate([-n, -np.ones((*dist.shape, 1))], axis=-1)[..., None, :]
        dx = _gn_step(j, (1.0 / var)[..., None, None], (dist - r[..., None])[..., None])
        a, r = a + dx[..., :3], r + dx[..., 3]
    return a, r


def type_iii_rows(P, R, b, a, sig: NoiseSigmas):
    """Per-pose Type III pieces at (b, a): distance |v − a| (..., N), unit leg direction n
    (..., N, 3), the constraint's Jacobian on (b, a, r) (..., N, 1, 7) and its weight
    1 / var (..., N, 1, 1), with v = P + R b and var = nᵀ Σ_B n."""
    rb = _rotated(R, b)
    d = P + rb - a[..., None, :]
    dist = np.sqrt(np.einsum("...i,...i->...", d, d))
    n = d / dist[..., None]
    var = _point_var(R, b, n, sig, rb)
    jac = np.concatenate(
        [np.einsum("...ni,...nij->...nj", n, R), -n, -np.ones((*dist.shape, 1))], axis=-1
    )[..., None, :]
    return dist, n, jac, (1.0 / var)[..., None, None]


#: The relative decrease of the weighted cost below which :func:`refine_type_ii_iii` counts a
#: member as converged (its step is then a few nanometres, a millionth of the noise).
CONVERGED = 1e-12
#: The relative decrease of the weighted cost below which :func:`refine_type_ii_iii` takes a
#: member's step as its last.
FINAL = 1e-6


#: The columns of θ = (b, C, a, r) a Type III pose's row has: b, a and r.
_TYPE_III = np.array([0, 1, 2, 6, 7, 8, 9])


def refine_type_ii_iii(P2, R2, P3, R3, b0, c0, a0, r0, sig: NoiseSigmas, iterations: int = 4):
    """The paper's §3.3 pose sets fitted together: a Type II set (``P2`` (..., N1, 3), ``R2``)
    and a Type III set (``P3`` (..., N, 3), ``R3``) of the same leg share its platform point b,
    so θ = (b, C, a, r) is fitted to both at once, each pose's constraint weighted by its
    propagated covariance (recomputed at every iteration): ``P + R b − C`` (Type II, 3 rows)
    and ``|P + R b − a| − r`` (Type III, 1 row). Seeds: b, C (..., 3) from the Type II set, a
    (..., 3), r (...,) from the Type III set. Returns (b, C, a, r)."""
    x = np.concatenate([b0, c0, a0, np.asarray(r0, float)[..., None]], axis=-1)
    eye = np.broadcast_to(np.eye(3), R2.shape)
    j2 = np.concatenate([R2, -eye], axis=-1)  # Type II's rows on (b, C), the first 6 of θ

    def terms(x, at=slice(None)):
        """The residuals, weights, Type III Jacobian and cost at x (the batch members ``at``)."""
        b, c, a, r = x[..., :3], x[..., 3:6], x[..., 6:9], x[..., 9]
        p2, r2 = P2[at], R2[at]
        res2 = p2 + _rotated(r2, b) - c[..., None, :]
        w2 = _inv3_sym(_point_cov(r2, b, sig))
        dist, _, j3, w3 = type_iii_rows(P3[at], R3[at], b, a, sig)
        res3 = (dist - r[..., None])[..., None]
        cost = np.einsum("...ni,...nij,...nj->...", res2, w2, res2)
        cost = cost + np.sum(w3[..., 0, 0] * res3[..., 0] ** 2, axis=-1)
        return [res2, w2, j3, w3, res3, cost]

    # One batch axis, so that the members still stepping can be picked out.
    batch = x.shape[:-1]
    x = x.reshape(-1, x.shape[-1])
    P2, R2 = P2.reshape(-1, *P2.shape[-2:]), R2.reshape(-1, *R2.shape[-3:])
    P3, R3 = P3.reshape(-1, *P3.shape[-2:]), R3.reshape(-1, *R3.shape[-3:])
    j2 = j2.reshape(-1, *j2.shape[-3:])
    now = terms(x)
    active = np.arange(len(x))
    for _ in range(iterations):
        res2, w2, j3, w3, res3, cost = (v[active] for v in now)
        # Each set's normal equations on its own unknowns, added into θ's: Type III's one row
        # a pose is weighted by a product, not a 1×1 matrix product per pose.
        jtj = np.zeros((len(active), 10, 10))
        jtr = np.zeros((len(active), 10, 1))
        jtj[:, :6, :6], jtr[:, :6] = _normal(j2[active], w2, res2)
        jw3 = np.swapaxes(j3[..., 0, :] * w3[..., 0, :], -1, -2)  # (A, 7, N)
        jtj[:, _TYPE_III[:, None], _TYPE_III] += jw3 @ j3[..., 0, :]
        jtr[:, _TYPE_III] += jw3 @ res3
        step = _solve_step(jtj, jtr)
        # A member whose step promises to lower its cost by less than CONVERGED of it is at
        # its minimum: its trial steps would only compare rounding errors (and be halved in
        # vain). It is left where it is, and no longer stepped.
        gain = -np.einsum("bi,bi->b", jtr[..., 0], step)
        moving = gain > CONVERGED * cost
        # A step that promises less than FINAL of the cost is the last: Gauss–Newton's next
        # would promise some 1e-8 of this one's (its rate is the residuals' curvature, noise
        # over a leg's length), below CONVERGED. So small a step cannot run away: it is taken
        # without trying it.
        last = moving & (gain <= FINAL * cost)
        x[active[last]] += step[last]
        moving &= ~last
        active, step = active[moving], step[moving]
        if not len(active):
            break
        dx = np.zeros_like(x)
        dx[active] = step
        # Step control: with few Type III poses the sphere is barely determined and a full
        # step can run away; a step that raises the weighted cost is halved, up to 6 times,
        # and a member whose every trial step does is left where it is. Only the members
        # still stepping are evaluated again.
        todo = active
        for _half in range(7):
            trial = x[todo] + dx[todo]
            got = terms(trial, todo)
            better = got[-1] <= now[-1][todo]
            took = todo[better]
            x[took] = trial[better]
            for kept, new in zip(now, got, strict=True):
                kept[took] = new[better]
            todo = todo[~better]
            if not len(todo):
                break
            dx = 0.5 * dx
        # A member whose every trial step failed is where it was: its next step would be the
        # same, and fail the same way. It is left there.
        active = np.setdiff1d(active, todo, assume_unique=True)
    x = x.reshape(*batch, x.shape[-1])
    return x[..., :3], x[..., 3:6], x[..., 6:9], x[..., 9]
