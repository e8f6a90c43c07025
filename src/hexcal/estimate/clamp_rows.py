"""The clamps' own constraints as residual rows of the whole-robot fit.

A clamped pose says more than its six leg lengths: the clamp holds something of leg k fixed for
every pose of its step. The whole-robot refinement (:mod:`hexcal.estimate.refine`) adds, per pose, the
clamp's implicit constraint, with one nuisance unknown per step (the paper's eqs. 1, 9, 14):

* Type I (``direction``): ``P + R b_k − a_k − (ρ_k + Δρ_k) u = 0`` with u the step's unknown
  unit direction (2 tangent parameters). These three rows contain leg k's length equation, so
  that row is dropped.
* Type II (``direction+length``): ``P + R b_k − C = 0`` with C the step's fixed point (3).
* Type III (``length``): ``|P + R b_k − a_k| − r = 0`` with r the step's clamped length (1);
  leg k's length row stays (it carries the reading's noise, this row the tracker's).

Each pose's rows are laid out in a fixed (9,) frame — rows 0–5 the leg lengths, rows 6–8 the
clamp's — with a mask of the rows in use, so that the whitening by each pose's covariance
``J_z Σ_z J_zᵀ`` (J_z: the rows' derivatives with respect to the measured position, body-frame
rotation and six readings) stays one batched Cholesky factorisation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hexcal.estimate.layout import ParameterLayout
from hexcal.vocabulary import Constraint

#: Rows per pose in the fixed layout: six leg lengths and up to three clamp rows.
ROWS = 9
#: Nuisance unknowns per step, by constraint.
N_NUISANCE = {Constraint.DIRECTION: 2, Constraint.DIRECTION_LENGTH: 3, Constraint.LENGTH: 1}
_NUISANCE_LABELS = {
    Constraint.DIRECTION: ("u.t1", "u.t2"),
    Constraint.DIRECTION_LENGTH: ("C.x", "C.y", "C.z"),
    Constraint.LENGTH: ("r",),
}


@dataclass(frozen=True)
class ClampSteps:
    """The clamped steps of a session: which poses share which clamp.

    ``group`` (M,) is each pose's step index (−1 for a free pose); ``leg`` (G,) the clamped
    leg, 0-based; ``kind`` (G,) the constraint; ``label`` (G,) the step's name for messages.
    """

    group: np.ndarray
    leg: np.ndarray
    kind: tuple[Constraint, ...]
    label: tuple[str, ...]

    @classmethod
    def from_table(cls, leg, constraint, step=None) -> ClampSteps:
        """From the measurement table's columns: leg (M,) 1..6 or 0, constraint (M,) str,
        step (M,) str (the procedure step; poses of one step share one clamp). Without ``step``
        every pose with the same leg and constraint shares one clamp, as the linear methods
        assume."""
        leg = np.asarray(leg, int)
        constraint = np.asarray(constraint, dtype=object)
        step = np.full(len(leg), "", dtype=object) if step is None else np.asarray(step, object)
        keys: dict[tuple, int] = {}
        group = np.full(len(leg), -1)
        for i, (k, c, s) in enumerate(zip(leg, constraint, step, strict=True)):
            if c not in N_NUISANCE or not 1 <= k <= 6:
                continue
            group[i] = keys.setdefault((int(k), str(c), str(s)), len(keys))
        ordered = sorted(keys, key=keys.__getitem__)
        return cls(
            group,
            np.array([k - 1 for k, _, _ in ordered], int),
            tuple(Constraint(c) for _, c, _ in ordered),
            tuple(s or f"leg{k}-{c}" for k, c, s in ordered),
        )

    def __len__(self) -> int:
        return len(self.kind)

    @property
    def n_nuisance(self) -> int:
        return sum(N_NUISANCE[c] for c in self.kind)

    @property
    def nuisance_names(self) -> list[str]:
        return [
            f"{lab}:{n}"
            for lab, c in zip(self.label, self.kind, strict=True)
            for n in _NUISANCE_LABELS[c]
        ]


@dataclass
class Nuisance:
    """Per-step nuisance values: unit direction u (G, 3) for Type I, point C (G, 3) mm for
    Type II, length r (G,) mm for Type III (unused entries are left at zero)."""

    u: np.ndarray
    C: np.ndarray
    r: np.ndarray

    @classmethod
    def seed(cls, steps: ClampSteps, a, b, P, R) -> Nuisance:
        """Each step's value from the poses at the geometry (a, b) (6, 3) mm: mean direction,
        mean point, mean length of the clamped leg."""
        g = len(steps)
        u, C, r = np.zeros((g, 3)), np.zeros((g, 3)), np.zeros(g)
        for s in range(g):
            m = steps.group == s
            k = steps.leg[s]
            p = P[m] + R[m] @ b[k]
            v = p - a[k]
            if steps.kind[s] == Constraint.DIRECTION:
                d = np.mean(v / np.linalg.norm(v, axis=-1, keepdims=True), axis=0)
                u[s] = d / np.linalg.norm(d)
            elif steps.kind[s] == Constraint.DIRECTION_LENGTH:
                C[s] = p.mean(axis=0)
            else:
                r[s] = np.linalg.norm(v, axis=-1).mean()
        return cls(u, C, r)


def tangent_bases(u: np.ndarray) -> np.ndarray:
    """(G, 3, 2) orthonormal bases of the planes normal to the unit vectors u (G, 3)."""
    helper = np.where(np.abs(u[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(u, helper)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(u, e1)
    return np.stack([e1, e2], axis=-1)


def _skew(b: np.ndarray) -> np.ndarray:
    """(..., 3, 3) matrices [b]× with [b]× x = b × x."""
    z = np.zeros(b.shape[:-1])
    return np.stack(
        [
            np.stack([z, -b[..., 2], b[..., 1]], -1),
            np.stack([b[..., 2], z, -b[..., 0]], -1),
            np.stack([-b[..., 1], b[..., 0], z], -1),
        ],
        -2,
    )


@dataclass
class ClampModel:
    """Residuals, parameter Jacobian and measurement Jacobian of every pose in the 9-row frame.

    The parameter vector is ``x = [geometry (36), offsets (6 if fitted), θ (q), nuisance]``
    (:attr:`layout`, then the nuisance after its :attr:`~ParameterLayout.size`); the nuisance
    block holds each step's unknowns in step order, Type I's as tangent coordinates
    about ``u0`` (so a pass re-centres them at zero).
    """

    steps: ClampSteps
    P: np.ndarray  #: (M, 3) mm
    R: np.ndarray  #: (M, 3, 3)
    rho: np.ndarray  #: (M, 6) mm
    fixed_offsets: np.ndarray  #: (6,) mm
    fit_offsets: bool
    basis: np.ndarray  #: (M, 6, q)
    u0: np.ndarray  #: (G, 3) Type I reference directions

    def __post_init__(self) -> None:
        self.tangent = tangent_bases(
            np.where(np.any(self.u0, -1, keepdims=True), self.u0, [0, 0, 1.0])
        )
        self.offset_of = np.cumsum([0] + [N_NUISANCE[c] for c in self.steps.kind])
        m = len(self.P)
        g = self.steps.group
        k = np.where(g >= 0, self.steps.leg[np.maximum(g, 0)], -1)
        kind = np.array(
            [self.steps.kind[s] if s >= 0 else Constraint.FREE for s in g], dtype=object
        )
        self.pose_leg = k
        self.pose_kind = kind
        mask = np.zeros((m, ROWS), bool)
        mask[:, :6] = True
        t1 = kind == Constraint.DIRECTION
        t2 = kind == Constraint.DIRECTION_LENGTH
        t3 = kind == Constraint.LENGTH
        mask[np.where(t1)[0], k[t1]] = False
        mask[t1 | t2, 6:9] = True
        mask[t3, 6] = True
        self.mask = mask

    @property
    def layout(self) -> ParameterLayout:
        """The blocks of x before the nuisance: a, b, the offsets when fitted, θ (q)."""
        return ParameterLayout(self.fit_offsets, self.basis.shape[-1])

    @property
    def n_rows(self) -> int:
        return int(self.mask.sum())

    def nuisance_vector(self, nu: Nuisance) -> np.ndarray:
        out: list[np.ndarray] = []
        for s, c in enumerate(self.steps.kind):
            if c == Constraint.DIRECTION:
                out.append(np.zeros(2))
            elif c == Constraint.DIRECTION_LENGTH:
                out.append(nu.C[s])
            else:
                out.append(np.array([nu.r[s]]))
        return np.concatenate(out) if out else np.zeros(0)

    def nuisance_values(self, x: np.ndarray) -> Nuisance:
        g = len(self.steps)
        u, C, r = np.zeros((g, 3)), np.zeros((g, 3)), np.zeros(g)
        z = x[len(x) - self.steps.n_nuisance :] if self.steps.n_nuisance else x[:0]
        for s, c in enumerate(self.steps.kind):
            blk = z[self.offset_of[s] : self.offset_of[s + 1]]
            if c == Constraint.DIRECTION:
                w = self.u0[s] + self.tangent[s] @ blk
                u[s] = w / np.linalg.norm(w)
            elif c == Constraint.DIRECTION_LENGTH:
                C[s] = blk
            else:
                r[s] = blk[0]
        return Nuisance(u, C, r)

    def evaluate(self, x: np.ndarray, want_jac: bool = True, want_jz: bool = True):
        """Residual (M, 9), Jacobian (M, 9, p) wrt x, and J_z (M, 9, 12) wrt the measurement
        (position 3, body-frame rotation 3, readings 6); rows not in use are zero. The
        derivatives not asked for come back as None."""
        m = len(self.P)
        q = self.basis.shape[-1]
        p = len(x)
        lay = self.layout
        if p != lay.size + self.steps.n_nuisance:
            raise ValueError(f"x has {p} entries, not {lay.size} + {self.steps.n_nuisance}")
        a, b = lay.a(x), lay.b(x)
        off = lay.offsets(x, self.fixed_offsets)
        eff = lay.effects_slice  # θ's columns; the nuisance follows from lay.size
        theta = x[eff]
        legs = np.arange(6)
        rb = np.einsum("mij,kj->mki", self.R, b)  # (M, 6, 3)
        v = self.P[:, None, :] + rb - a[None]
        length = np.linalg.norm(v, axis=-1)
        n = v / length[..., None]
        extra = self.basis @ theta if q else np.zeros((m, 6))
        pred = self.rho + off + extra  # predicted geometric length (M, 6)

        res = np.zeros((m, ROWS))
        # Derivatives not asked for are written into scratch arrays and dropped.
        jac = np.zeros((m, ROWS, p) if want_jac else (m, ROWS, 0))
        jz = np.zeros((m, ROWS, 12) if want_jz else (m, ROWS, 0))
        res[:, :6] = length - pred
        rtn = np.einsum("mji,mkj->mki", self.R, n)
        if want_jac:
            for axis in range(3):
                jac[:, legs, lay.a_column(legs, axis)] = -n[:, :, axis]
                jac[:, legs, lay.b_column(legs, axis)] = rtn[:, :, axis]
            if self.fit_offsets:
                jac[:, legs, lay.offset_column(legs)] = -1.0
            if q:
                jac[:, :6, eff] = -self.basis
        g_rows = np.cross(b[None], rtn)  # dL/dθ body, (M, 6, 3)
        if want_jz:
            jz[:, :6, 0:3] = n
            jz[:, :6, 3:6] = g_rows
            jz[:, legs, 6 + legs] = -1.0

        nu = self.nuisance_values(x)
        rows = np.arange(m)
        for s, c in enumerate(self.steps.kind):
            sel = rows[self.steps.group == s]
            if not len(sel):
                continue
            k = self.steps.leg[s]
            col = lay.size + self.offset_of[s]
            geo_a, geo_b = lay.a_of_leg(k), lay.b_of_leg(k)
            if want_jz and c != Constraint.LENGTH:
                jz[sel, 6:9, 0:3] = np.eye(3)
                jz[sel, 6:9, 3:6] = -self.R[sel] @ _skew(b[k])  # d(R b)/dθ body
            if c == Constraint.DIRECTION:
                u = nu.u[s]
                s_len = pred[sel, k]  # (n,)
                res[sel, 6:9] = v[sel, k] - s_len[:, None] * u
                # Leg k's length row is the component of these rows along u: not used.
                res[sel, k] = 0.0
                if want_jac:
                    jac[sel, k] = 0.0
                    jac[sel, 6:9, geo_a] = -np.eye(3)
                    jac[sel, 6:9, geo_b] = self.R[sel]
                    if self.fit_offsets:
                        jac[sel, 6:9, lay.offset_column(k)] = -u
                    if q:
                        jac[sel, 6:9, eff] = -u[None, :, None] * self.basis[sel, k][:, None, :]
                    w = self.u0[s] + self.tangent[s] @ x[col : col + 2]
                    du = (np.eye(3) - np.outer(u, u)) / np.linalg.norm(w) @ self.tangent[s]
                    jac[sel, 6:9, col : col + 2] = -s_len[:, None, None] * du[None]
                if want_jz:
                    jz[sel, k] = 0.0
                    jz[sel, 6:9, 6 + k] = -u
            elif c == Constraint.DIRECTION_LENGTH:
                res[sel, 6:9] = self.P[sel] + rb[sel, k] - x[col : col + 3]
                if want_jac:
                    jac[sel, 6:9, geo_b] = self.R[sel]
                    jac[sel, 6:9, col : col + 3] = -np.eye(3)
            else:
                res[sel, 6] = length[sel, k] - x[col]
                if want_jac:
                    jac[sel, 6, geo_a] = -n[sel, k]
                    jac[sel, 6, geo_b] = rtn[sel, k]
                    jac[sel, 6, col] = -1.0
                if want_jz:
                    jz[sel, 6, 0:3] = n[sel, k]
                    jz[sel, 6, 3:6] = g_rows[sel, k]
        return res, (jac if want_jac else None), (jz if want_jz else None)

    def whiteners(self, x: np.ndarray, sig_p: float, sig_th: float, sig_rho: float) -> np.ndarray:
        """W (M, 9, 9) with ``W S Wᵀ = I`` on the rows in use, S = J_z Σ_z J_zᵀ."""
        _, _, jz = self.evaluate(x, want_jac=False)
        d = np.array([sig_p] * 3 + [sig_th] * 3 + [sig_rho] * 6) ** 2
        S = np.einsum("mia,a,mja->mij", jz, d, jz)
        S = S + np.einsum("mi,ij->mij", (~self.mask).astype(float), np.eye(ROWS))
        return np.linalg.inv(np.linalg.cholesky(S))
