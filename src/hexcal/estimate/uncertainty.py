"""The uncertainty of a computed pose, in the sense of the GUM (JCGM 100:2008), to first order.

A calibrated model turns six readings into a pose by solving

    f(pose, θ, ρ) = |P + R b_k − a_k| − (ρ_k + offset_k + Σ_effects basis_k(ρ, pose) · θ) = 0

for the pose. Its inputs are uncertain: the model's parameters θ (the geometry a, b, the offsets
of Model 42 and the effect parameters) with the covariance Σ_θ of the fit (calibrated.json's
``calibration.covariance``), and the six readings with the encoders' noise σ_ρ. The law of
propagation of uncertainty (GUM 5.2, the input quantities correlated through Σ_θ) gives the
covariance of the pose (N, 6, 6) — translation mm, then a small rotation in the measurement frame
(rad) —

    Σ_pose = J_p⁻¹ (J_θ Σ_θ J_θᵀ + σ_ρ² I) J_p⁻ᵀ,

with J_p (6, 6) the platform Jacobian (rows ``[n_k, (R b_k) × n_k]``) and J_θ (6, p) the
derivative of ``f`` in θ (``−n_k`` for a_k, ``Rᵀ n_k`` for b_k, ``−1`` for offset_k, ``−basis``
for the effects). The readings enter with unit sensitivity: a gain or a lead-screw error changes
it by at most a few per cent (first order, GUM 5.1.2).

**Expanded uncertainty** (GUM 6.2, coverage factor k = 2): for position, ``U = 2 √λ_max`` of
the 3×3 position block, the semi-axis of the k = 2 ellipsoid along its longest direction, so
the error along any direction has an expanded uncertainty of at most U (mm); for orientation the
same of the rotation block, in degrees.

**Terms beyond the parameters and the readings** (:class:`SessionTerms`): the propagation
above assumes the model is right and the robot unchanged. Two more leg-length variances, each
independent per leg and per pose, join σ_ρ² where they are known: the **model inadequacy**
u_m² = max(0, h² − f² − K/(K − 1)·p²), what the fit's held-out leg residual h exceeds by the
floor f the noise gives and the parameters' share p, which the statement already holds (the
held-out fits use (K − 1)/K of the poses), counted where that excess is beyond the held-out
RMS's own scatter — what the model lacks, as it showed on poses the fit did not see; and the
**between-session** term u_b² = max(0, r² − h²), what a second session's leg residual r (the
model held fixed) exceeded h by (re-homing, what changes from day to day), once such a session
was validated; from one session it rests on six draws (one per leg), so it is stated widened by
t₆(0.975)/z(0.975) = 1.25 (:attr:`SessionTerms.between_stated_mm`).
``Σ_pose = J_p⁻¹ (J_θ Σ_θ J_θᵀ + (σ_ρ² + u_m² + u_b²) I) J_p⁻ᵀ``. Each is a
variance spread evenly over the legs and the poses: a term that is really a constant per leg (a
re-home) or follows the pose (an effect missing) is covered on average over poses, not pose by
pose.

**Coverage.** Against a tracker, the error of the computed pose also holds the tracker's own
noise (σ_p per axis, independent of the model): a pose's error ``Δp`` (3,) lies in its 95 %
region when ``Δpᵀ (Σ_pos + σ_p² I)⁻¹ Δp ≤ χ²₃(0.95) = 7.81``. :func:`coverage` is the fraction
of poses that do: 0.95 when the stated uncertainties are right.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hexcal.effects import get_effect
from hexcal.estimate.predict import LegModel, Poses
from hexcal.estimate.quantiles import chi2_ppf, norm_ppf, t_ppf

#: Coverage factor of the expanded uncertainties (GUM 6.2.1).
K = 2.0
#: Probability of the coverage regions compared with the errors.
COVERAGE_P = 0.95


@dataclass(frozen=True)
class ParameterCovariance:
    """The covariance of a model's parameters: ``names`` (p,) as the fit names them (``a1.x`` …
    ``b6.z``, ``offset1`` … when fitted, then the effect parameters) and ``matrix`` (p, p) in
    their units squared (mm², ppm², mm·ppm…)."""

    names: tuple[str, ...]
    matrix: np.ndarray

    def __post_init__(self) -> None:
        m = np.asarray(self.matrix, float)
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "matrix", m)
        p = len(self.names)
        if m.shape != (p, p):
            raise ValueError(f"the covariance of {p} parameters must be {p}×{p}, not {m.shape}")

    def subset(self, names: Sequence[str]) -> ParameterCovariance:
        """The marginal covariance of ``names`` (their rows and columns)."""
        idx = [self.names.index(n) for n in names]
        return ParameterCovariance(tuple(names), self.matrix[np.ix_(idx, idx)])

    @property
    def sigma(self) -> np.ndarray:
        """(p,) standard deviations in the parameters' units."""
        return np.sqrt(np.maximum(np.diag(self.matrix), 0.0))


def model_parameter_names(model: LegModel, fit_offsets: bool) -> list[str]:
    """The names of ``model``'s parameters in the fit's order: a, b, the offsets when fitted
    (Model 42), then its effects' parameters."""
    out = [f"{p}{k}.{c}" for p in "ab" for k in range(1, 7) for c in "xyz"]
    if fit_offsets:
        out += [f"offset{k}" for k in range(1, 7)]
    return out + [s.name for s in model.specs]


def parameter_jacobian(
    model: LegModel,
    names: Sequence[str],
    poses: Poses,
    readings: np.ndarray,
    t: np.ndarray | None = None,
    temperature: np.ndarray | None = None,
) -> np.ndarray:
    """(N, 6, p): ∂f/∂θ of the six legs at each pose for the parameters ``names`` (see the
    module docstring); a name the model does not have is refused."""
    P, R = poses.position, poses.rotation
    a, b = model.robot.a, model.robot.b
    v = P[:, None, :] + np.einsum("nij,kj->nki", R, b) - a[None]
    n = v / np.linalg.norm(v, axis=-1, keepdims=True)
    rtn = np.einsum("nji,nkj->nki", R, n)  # Rᵀ n_k: d|v|/db_k
    jac = np.zeros((len(P), 6, len(names)))
    column = {name: i for i, name in enumerate(names)}
    effect_names = [s.name for s in model.specs]
    basis = None
    if effect_names:
        data = model.data(readings, P, R, t, temperature)
        basis = np.concatenate([get_effect(e).basis(data) for e in model.effects], axis=-1)
    for name, i in column.items():
        if name in effect_names:
            jac[:, :, i] = -basis[:, :, effect_names.index(name)]  # type: ignore[index]
            continue
        kind, leg, axis = _geometry_name(name)
        if kind == "a":
            jac[:, leg, i] = -n[:, leg, axis]
        elif kind == "b":
            jac[:, leg, i] = rtn[:, leg, axis]
        else:
            jac[:, leg, i] = -1.0
    return jac


def _geometry_name(name: str) -> tuple[str, int, int]:
    """('a' | 'b' | 'offset', leg 0–5, axis 0–2) of a geometry parameter's name."""
    if name.startswith("offset") and name[6:].isdigit() and 1 <= int(name[6:]) <= 6:
        return "offset", int(name[6:]) - 1, 0
    if (
        len(name) == 4
        and name[0] in "ab"
        and name[1] in "123456"
        and name[2:] in (".x", ".y", ".z")
    ):
        return name[0], int(name[1]) - 1, ".x.y.z".index(name[2:]) // 2
    raise ValueError(f"{name!r} is neither a geometry parameter nor one of the model's effects")


def platform_jacobian(model: LegModel, poses: Poses) -> np.ndarray:
    """(N, 6, 6) ∂|v_k|/∂(P, φ): rows ``[n_k, (R b_k) × n_k]``, φ a small rotation in the
    measurement frame."""
    a, b = model.robot.a, model.robot.b
    rb = np.einsum("nij,kj->nki", poses.rotation, b)
    v = poses.position[:, None, :] + rb - a[None]
    n = v / np.linalg.norm(v, axis=-1, keepdims=True)
    return np.concatenate([n, np.cross(rb, n)], axis=-1)


#: Degrees of freedom of a between-session term from one session: what changes between
#: sessions (a re-home) is one draw per leg.
SESSION_DOF = 6


@dataclass(frozen=True)
class SessionTerms:
    """The leg-length uncertainty terms beyond the parameters and the readings (mm, 1σ per leg;
    see the module docstring): ``model_inadequacy_mm`` (the fit's held-out residual above its
    floor) and ``between_session_mm`` (a validated second session's residual above the fit's
    held-out one; None until one was), estimated with ``between_session_dof`` degrees of
    freedom."""

    model_inadequacy_mm: float = 0.0
    between_session_mm: float | None = None
    between_session_dof: int = SESSION_DOF

    @property
    def between_stated_mm(self) -> float:
        """u_b as stated: the estimate times t_ν(0.975) / z(0.975) (GUM G.3: a Type A term of
        few degrees of freedom ν widens the interval as Student's t does); 0 without one."""
        if self.between_session_mm is None:
            return 0.0
        widen = t_ppf(0.975, self.between_session_dof) / float(norm_ppf(0.975))
        return float(self.between_session_mm * widen)

    @property
    def variance_mm2(self) -> float:
        """u_m² + u_b², mm²: what joins the readings' variance."""
        return self.model_inadequacy_mm**2 + self.between_stated_mm**2


def excess_mm(rms_mm: float, below_mm: float) -> float:
    """√max(0, rms² − below²), mm: what a residual RMS exceeds a level by, in quadrature
    (u_m from the held-out residual and its floor, u_b from a second session's residual and the
    held-out one); 0 where either is unknown."""
    if not (np.isfinite(rms_mm) and np.isfinite(below_mm)):
        return 0.0
    return float(np.sqrt(max(rms_mm**2 - below_mm**2, 0.0)))


def parameter_leg_rms_mm(model: LegModel, names: Sequence[str], matrix: np.ndarray, meas) -> float:
    """p, mm: the RMS over the table ``meas``'s poses and legs of the leg-length uncertainty the
    parameters' covariance (``names``, ``matrix`` (p, p)) gives, √mean diag(J_θ Σ_θ J_θᵀ) at
    the measured poses — the share of a held-out residual the statement already holds."""
    poses = Poses(meas.position, meas.rotations.as_matrix())
    jac = parameter_jacobian(model, names, poses, meas.readings, meas.t, meas.temperature)
    var = np.einsum("nkp,pq,nkq->nk", jac, np.asarray(matrix, float), jac)
    return float(np.sqrt(max(float(np.mean(var)), 0.0)))


def pose_covariance(
    model: LegModel,
    covariance: ParameterCovariance | None,
    poses: Poses,
    readings: np.ndarray,
    reading_sigma_mm: float,
    t: np.ndarray | None = None,
    temperature: np.ndarray | None = None,
    extra_variance_mm2: float = 0.0,
) -> np.ndarray:
    """(N, 6, 6) covariance of the poses the model computes from ``readings`` (N, 6) mm at
    ``poses``: translation (mm²) then rotation (rad², measurement frame). ``covariance`` None:
    the readings' noise alone (the parameters taken as exact). ``extra_variance_mm2``: the
    :class:`SessionTerms`' leg-length variance, beside the readings'."""
    jp_inv = np.linalg.inv(platform_jacobian(model, poses))
    var = reading_sigma_mm**2 + extra_variance_mm2
    inner = np.broadcast_to(var * np.eye(6), (len(poses.position), 6, 6)).copy()
    if covariance is not None:
        jt = parameter_jacobian(model, covariance.names, poses, readings, t, temperature)
        inner += jt @ covariance.matrix @ jt.transpose(0, 2, 1)
    return jp_inv @ inner @ jp_inv.transpose(0, 2, 1)


@dataclass(frozen=True)
class PoseUncertainty:
    """Per pose (N,): the expanded uncertainties (k = 2) of the computed pose, position mm and
    orientation degrees, and the covariance (N, 6, 6) they come from."""

    position_mm: np.ndarray
    orientation_deg: np.ndarray
    covariance: np.ndarray

    @classmethod
    def of(cls, cov: np.ndarray) -> PoseUncertainty:
        pos = np.linalg.eigvalsh(cov[:, :3, :3])[:, -1]
        ori = np.linalg.eigvalsh(cov[:, 3:, 3:])[:, -1]
        return cls(
            K * np.sqrt(np.maximum(pos, 0.0)),
            np.degrees(K * np.sqrt(np.maximum(ori, 0.0))),
            cov,
        )


def pose_uncertainty(
    model: LegModel,
    covariance: ParameterCovariance | None,
    poses: Poses,
    readings: np.ndarray,
    reading_sigma_mm: float,
    t: np.ndarray | None = None,
    temperature: np.ndarray | None = None,
    extra_variance_mm2: float = 0.0,
) -> PoseUncertainty:
    """The expanded uncertainties of the poses ``model`` computes from ``readings`` (see
    :func:`pose_covariance`)."""
    cov = pose_covariance(
        model, covariance, poses, readings, reading_sigma_mm, t, temperature, extra_variance_mm2
    )
    return PoseUncertainty.of(cov)


def coverage(
    errors_mm: np.ndarray, covariance: np.ndarray, tracker_sigma_mm: float
) -> tuple[float, np.ndarray]:
    """(fraction, inside (N,) bool): which position errors ``errors_mm`` (N, 3) — the computed
    pose less the tracker's — lie in their 95 % region, the model's position covariance
    ``covariance`` (N, 3, 3) mm² plus the tracker's ``tracker_sigma_mm`` per axis."""
    total = covariance + tracker_sigma_mm**2 * np.eye(3)
    d2 = np.einsum("ni,ni->n", errors_mm, np.linalg.solve(total, errors_mm[..., None])[..., 0])
    inside = d2 <= chi2_ppf(COVERAGE_P, 3)
    return (float(inside.mean()) if len(inside) else float("nan")), inside
