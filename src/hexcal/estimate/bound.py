"""The accuracy limit: the KCR (Kanatani–Cramér–Rao) bound of one leg's clamp constraint.

Each pose i gives an implicit constraint ``g(θ, z_i) = 0`` between the leg's parameters θ and
what is measured at that pose, z_i = (P_i, the small rotation of R_i about the platform axes,
the reading ρ_i), with Gaussian noise of covariance Σ_z. The true poses are nuisance unknowns;
eliminating them (the Schur complement of the full Fisher matrix, first order in the noise)
leaves the information

    M = Σ_i J_θ,iᵀ (J_z,i Σ_z J_z,iᵀ)⁻¹ J_θ,i

on θ, and no unbiased estimator does better than cov(θ̂) ≥ M⁻¹ (Kanatani 1996; Chernov &
Lesort 2004). The constraints, parameters and gauge:

* Type I (direction clamped): ``P + R b − a − ρ u = 0`` (3 per pose), θ = (b, a, u) with |u|
  = 1: u varies in its tangent plane (2 coordinates), so M is 8×8;
* Type II (direction and length): ``P + R b − C = 0`` (3 per pose), θ = (b, C), 6×6;
* Type III (length): ``|P + R b − a| − r = 0`` (1 per pose), θ = (a, r) with b known, 4×4;
* Types II and III together (the paper's §3.3: b from the Type II set, a and r from the Type
  III set through that same b), θ = (b, C, a, r), 10×10.

``J_z Σ_z J_zᵀ`` is the covariance of the constraint at the truth: position σp² I, the
orientation σθ² (R[b]×)(R[b]×)ᵀ (a body-frame rotation, as :class:`~hexcal.sim.simulate.NoiseModel`
applies it), and for Type I the reading σρ² u uᵀ. Shapes: ``P`` (..., N, 3) mm, ``R`` (..., N,
3, 3), ``length`` (..., N) mm; the bound is batched over any leading axes.
"""

from __future__ import annotations

import numpy as np

from hexcal.estimate.solvers.linalg import running_sums
from hexcal.estimate.solvers.paper import Counts
from hexcal.estimate.solvers.weighted import (
    _inv3_sym,
    _normal,
    _point_cov,
    _tangent_basis,
    type_iii_rows,
)
from hexcal.model.noise import NoiseSigmas


def _information(jac: np.ndarray, w: np.ndarray, counts: Counts = None) -> np.ndarray:
    """Σ_i J_iᵀ W_i J_i (..., p, p) from jac (..., N, q, p) and weights w (..., N, q, q).

    ``counts`` (C,): the sums over the first counts[c] poses, (..., C, p, p) — the information
    of nested pose sets, each pose's own summed once (the information of independent poses
    adds up)."""
    if counts is None:
        return _normal(jac, w, np.zeros(jac.shape[:-1]))[0]
    per_pose = np.einsum("...nqi,...nqj->...nij", jac, w @ jac)
    return running_sums(per_pose, counts, axis=-3)


def information_type_i(P, R, length, b, a, u, sig: NoiseSigmas, counts: Counts = None):
    """Fisher information (..., 8, 8) on (b, a, u's two tangent coordinates); with ``counts``,
    (..., C, 8, 8) of the first counts[c] poses of each set (:func:`_information`)."""
    del a  # the constraint is linear in a: its information does not depend on it
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    cov = (
        _point_cov(R, b, sig)
        + sig.reading_mm**2 * (u[..., :, None] * u[..., None, :])[..., None, :, :]
    )
    e1, e2 = _tangent_basis(u)
    lt = -np.asarray(length)[..., None, None]
    eye = np.broadcast_to(np.eye(3), R.shape)
    jac = np.concatenate([R, -eye, lt * e1[..., None, :, None], lt * e2[..., None, :, None]], -1)
    return _information(jac, _inv3_sym(cov), counts)


def information_type_ii(P, R, b, sig: NoiseSigmas, counts: Counts = None) -> np.ndarray:
    """Fisher information (..., 6, 6) on (b, C) (``counts``: as :func:`information_type_i`)."""
    jac = np.concatenate([R, -np.broadcast_to(np.eye(3), R.shape)], axis=-1)
    return _information(jac, _inv3_sym(_point_cov(R, b, sig)), counts)


def information_type_iii(
    P, R, b, a, sig: NoiseSigmas, with_b: bool = False, counts: Counts = None
) -> np.ndarray:
    """Fisher information (..., 4, 4) on (a, r), b known; with ``with_b``, (..., 7, 7) on
    (b, a, r) — alone singular along b (a sphere fixes only |P + R b − a|), it is what a
    Type III set adds when b is estimated too (:func:`information_type_ii_iii`). ``counts``:
    as :func:`information_type_i`."""
    _, _, jac, w = type_iii_rows(P, R, b, a, sig)
    return _information(jac if with_b else jac[..., 3:], w, counts)


def information_type_ii_iii(P2, R2, P3, R3, b, a, sig: NoiseSigmas, counts: Counts = None):
    """Fisher information (..., 10, 10) on (b, C, a, r) of the paper's §3.3 pose sets taken
    together: a Type II set (fixes b and C) and a Type III set (a and r, through the same b);
    with ``counts``, (..., C, 10, 10) of the whole Type II set and the first counts[c] poses
    of the Type III set."""
    info3 = information_type_iii(P3, R3, b, a, sig, with_b=True, counts=counts)
    info = np.zeros((*info3.shape[:-2], 10, 10))
    info2 = information_type_ii(P2, R2, b, sig)
    info[..., :6, :6] = info2 if counts is None else info2[..., None, :, :]
    idx = np.r_[0:3, 6:10]
    info[..., idx[:, None], idx[None, :]] += info3
    return info


#: A pose set whose information, scaled to a unit diagonal, has a Cholesky pivot² below this
#: (a condition number beyond about 1e12) leaves a direction barely determined: its bound is
#: the pseudo-inverse.
WELL_POSED_PIVOT = 1e-12


def bound(information: np.ndarray) -> np.ndarray:
    """The KCR bound (..., p, p): the inverse information (a pseudo-inverse where a pose set
    leaves a direction undetermined, which then shows as a huge variance).

    The inverse of the well-posed ones is taken on the information scaled to a unit diagonal
    (their Cholesky factor tells them apart); the pseudo-inverse, an eigendecomposition, is
    eight times slower and taken for the others only (:data:`WELL_POSED_PIVOT`)."""
    info = np.asarray(information, float)
    d = np.sqrt(np.abs(np.diagonal(info, axis1=-2, axis2=-1)))
    s = 1.0 / np.where(d > 0, d, 1.0)
    scaled = info * s[..., :, None] * s[..., None, :]
    try:
        pivots = np.diagonal(np.linalg.cholesky(scaled), axis1=-2, axis2=-1) ** 2
        well = np.all((pivots > WELL_POSED_PIVOT) & (d > 0), axis=-1)
    except np.linalg.LinAlgError:
        well = np.zeros(info.shape[:-2], bool)
    if np.all(well):
        return np.linalg.inv(scaled) * (s[..., :, None] * s[..., None, :])
    out = np.empty_like(info)
    out[~well] = np.linalg.pinv(info[~well], hermitian=True)
    if np.any(well):
        out[well] = np.linalg.inv(scaled[well]) * (s[well][..., :, None] * s[well][..., None, :])
    return out


def base_point_mse_bound(information: np.ndarray, pose_type: str) -> np.ndarray:
    """The bound on E‖â − a‖² (..., ) mm² (Types I and III, and Types II + III together), or
    on E‖b̂ − b‖² (Type II)."""
    cov = bound(information)
    block = {
        "type_i": slice(3, 6),
        "type_ii": slice(0, 3),
        "type_iii": slice(0, 3),
        "type_ii_iii": slice(6, 9),
    }[pose_type]
    return np.trace(cov[..., block, block], axis1=-2, axis2=-1)


def platform_point_mse_bound(information: np.ndarray) -> np.ndarray:
    """The bound on E‖b̂ − b‖² (..., ) mm² for Types I and II (b comes first)."""
    return np.trace(bound(information)[..., :3, :3], axis1=-2, axis2=-1)
