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
* Type III (length): ``|P + R b − a| − r = 0`` (1 per pose), θ = (a, r) with b known, 4×4.

``J_z Σ_z J_zᵀ`` is the covariance of the constraint at the truth: position σp² I, the
orientation σθ² (R[b]×)(R[b]×)ᵀ (a body-frame rotation, as :class:`~hexcal.simulate.NoiseModel`
applies it), and for Type I the reading σρ² u uᵀ. Shapes: ``P`` (..., N, 3) mm, ``R`` (..., N,
3, 3), ``length`` (..., N) mm; the bound is batched over any leading axes.
"""

from __future__ import annotations

import numpy as np

from hexcal.noise import NoiseSigmas
from hexcal.solvers.weighted import _inv3_sym, _point_cov, _tangent_basis


def _information(jac: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Σ_i J_iᵀ W_i J_i (..., p, p) from jac (..., N, q, p) and weights w (..., N, q, q)."""
    return np.sum(np.swapaxes(jac, -1, -2) @ w @ jac, axis=-3)


def information_type_i(P, R, length, b, a, u, sig: NoiseSigmas) -> np.ndarray:
    """Fisher information (..., 8, 8) on (b, a, u's two tangent coordinates)."""
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
    return _information(jac, _inv3_sym(cov))


def information_type_ii(P, R, b, sig: NoiseSigmas) -> np.ndarray:
    """Fisher information (..., 6, 6) on (b, C)."""
    jac = np.concatenate([R, -np.broadcast_to(np.eye(3), R.shape)], axis=-1)
    return _information(jac, _inv3_sym(_point_cov(R, b, sig)))


def information_type_iii(P, R, b, a, sig: NoiseSigmas) -> np.ndarray:
    """Fisher information (..., 4, 4) on (a, r), b known."""
    v = P + (R @ b[..., None, :, None])[..., 0]
    d = v - a[..., None, :]
    n = d / np.linalg.norm(d, axis=-1, keepdims=True)
    var = (n[..., None, :] @ _point_cov(R, b, sig) @ n[..., :, None])[..., 0, 0]
    jac = np.concatenate([-n, -np.ones((*n.shape[:-1], 1))], axis=-1)[..., None, :]
    return _information(jac, (1.0 / var)[..., None, None])


def bound(information: np.ndarray) -> np.ndarray:
    """The KCR bound (..., p, p): the inverse information (a pseudo-inverse where a pose set
    leaves a direction undetermined, which then shows as a huge variance)."""
    return np.linalg.pinv(information, hermitian=True)


def base_point_mse_bound(information: np.ndarray, pose_type: str) -> np.ndarray:
    """The bound on E‖â − a‖² (..., ) mm² (Types I and III), or on E‖b̂ − b‖² (Type II)."""
    cov = bound(information)
    block = {"type_i": slice(3, 6), "type_ii": slice(0, 3), "type_iii": slice(0, 3)}[pose_type]
    return np.trace(cov[..., block, block], axis1=-2, axis2=-1)


def platform_point_mse_bound(information: np.ndarray) -> np.ndarray:
    """The bound on E‖b̂ − b‖² (..., ) mm² for Types I and II (b comes first)."""
    return np.trace(bound(information)[..., :3, :3], axis1=-2, axis2=-1)
