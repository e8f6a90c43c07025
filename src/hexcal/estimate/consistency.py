"""The data's own consistency, checked before any fit: units, signs, quaternion order, swapped
legs, a drawing in other units, leg offsets — each named with its fix in milliseconds, instead
of a fit that runs for minutes and then diverges or calls the user's files invalid.

For each leg the squared inverse kinematics ``|P + R b − a|² = (s ρ + Δ)²`` is linear in b (3),
a (3), the nine products a_i b_j, ``|a|² + |b|² − Δ²``, ``s²`` and ``s Δ`` once the products
are freed from a and b (the free-pose form of :mod:`hexcal.estimate.solvers.free`, with the
reading's scale ``s`` as one more unknown). Its least-squares solution needs no drawing and no
registered frames, and tells, per leg:

- ``s``: how fast the length the tracker implies changes against the reading — 1 for a reading
  in mm, 10 for one in cm, 25.4 in inches, −1 for a reading that runs backwards (the sign comes
  from the length, which must be positive); a hand-measured mm-per-count a few per cent off
  gives 0.95..1.05, which the ``gain`` effect then fits;
- the residual (mm): the tracker and the readings agree to the noise when the quaternions are
  read in their true order, and to tenths of a mm or worse when not, so the two orders
  (scalar first, as the table says, and scalar last) are both tried;
- a, b and Δ, to compare with the drawing: the size of the geometry (a drawing in cm, or a
  table whose positions and readings are both in cm, is 10× off), which drawing leg each
  column's points lie at (swapped columns), and the offsets.

Findings that need the drawing say so (``drawing``): with the drawing check off, they are
reported but refuse nothing. :func:`likely_causes` ranks the same signature for a fit that did
not converge or diverged. Everything here is linear algebra on (N, 18) matrices: about 10 ms
for 200 poses.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.estimate.sanity import DRAWING_TOLERANCE, check_against_drawing, drawing_tolerances
from hexcal.estimate.solvers.free import free_linear
from hexcal.model.robot import Robot

#: Fewer poses than this leave the 18 unknowns of a leg too loosely determined to judge.
MIN_POSES = 30
#: A longer session is judged on this many poses spread evenly over it: a slip of units,
#: signs, order or columns shows on every pose, and 10,000 determine each leg's 18 unknowns
#: far inside the tolerances judged here (a 120,000-pose recording took 6.6 s, now 0.5 s).
CHECK_POSES = 10_000


@dataclass(frozen=True)
class _Rows:
    """The columns the check reads: position (N, 3) mm, quaternion (N, 4), readings (N, 6)."""

    position: np.ndarray
    quaternion: np.ndarray
    readings: np.ndarray

    @classmethod
    def spread(cls, meas) -> _Rows:
        """``meas``'s rows, at most :data:`CHECK_POSES` of them evenly spread over it."""
        n = len(meas.position)
        if n <= CHECK_POSES:
            return cls(meas.position, meas.quaternion, meas.readings)
        rows = np.unique(np.linspace(0, n - 1, CHECK_POSES).round().astype(int))
        return cls(meas.position[rows], meas.quaternion[rows], meas.readings[rows])


#: A leg's reading scale outside this range cannot be a calibration error of a leg: it is a
#: unit (or the reading of something else). Inside it, the gain effect fits what is left.
SCALE_RANGE = (0.5, 2.0)
#: The other quaternion order is taken for the true one when its residual is this many times
#: smaller (the Jugglebot, read in its true order: 8×; the wrong order of a simulated session:
#: 50×)...
ORDER_RATIO = 4.0
#: ...and the order as read leaves at least this RMS, mm (far beyond any tracker's noise).
ORDER_MIN_MM = 0.05
#: A geometry this many times the drawing's (or its inverse) is a unit, not a calibration.
GEOMETRY_SCALE_RANGE = (0.5, 2.0)
#: A fitted point this many drawing tolerances from its own design point is flagged before the
#: fit (moderate distances are the fitted geometry's to judge, after it).
FAR_FACTOR = 3.0
#: The joints the free form gives are compared with the drawing only when their standard
#: error is at most this fraction of the drawing's tolerance.
POINTS_SIGMA_FRACTION = 0.1
#: Known factors between units of length, for the messages: factor -> what it suggests.
UNITS = {
    10.0: "cm",
    25.4: "inches",
    1000.0: "m",
    100.0: "dm or hundredths of a mm",
    304.8: "feet",
}
#: A factor within this fraction of a known one is named as it.
UNIT_MATCH = 0.05


@dataclass(frozen=True)
class LegSignature:
    """One leg's relation between the tracker's lengths and its readings (column ``rho{leg}``).

    ``scale``: length change per reading change (1 for mm; its sign is the reading's
    direction); ``scale_sigma``: its standard error, NaN when the poses do not determine it;
    ``offset_mm``: the offset Δ at that scale; ``rms_mm``: the residual; ``a``, ``b`` (3,) mm:
    the joint points (tracker frame, tool frame); ``points_sigma_mm``: the largest standard
    error of their coordinates (NaN when the poses do not determine them: too little
    rotation); ``kept`` (N,) bool: the poses it was judged on (all but gross outliers)."""

    leg: int
    scale: float
    scale_sigma: float
    offset_mm: float
    rms_mm: float
    a: np.ndarray
    b: np.ndarray
    points_sigma_mm: float = float("nan")
    kept: np.ndarray | None = field(default=None, repr=False, compare=False)


@dataclass(frozen=True)
class Finding:
    """One inconsistency: ``cause`` (``quaternion-order``, ``sign``, ``units``,
    ``geometry-scale``, ``swapped``, ``other-leg``, ``far``, ``offset``), the legs (1-based),
    the message with its fix, whether it rests on the drawing, and ``strength`` (how clearly
    the data show it, for ranking: a ratio of residuals or of scales, ≥ 1)."""

    cause: str
    legs: tuple[int, ...]
    text: str
    drawing: bool
    strength: float = 1.0


@dataclass
class Consistency:
    """What the data say of themselves: the residual of each quaternion order (mm), the order
    that fits, each leg's signature in it, and the findings."""

    checked: bool
    orders: dict[str, float] = field(default_factory=dict)
    order: str = "wxyz"
    legs: list[LegSignature] = field(default_factory=list)
    findings: list[Finding] = field(default_factory=list)
    note: str = ""

    def refusals(self, drawing: bool = True) -> list[Finding]:
        """The findings that stop a calibration: all of them, or with the drawing check off
        those that need no drawing."""
        return [f for f in self.findings if drawing or not f.drawing]

    def warnings(self, drawing: bool = True) -> list[Finding]:
        """The findings reported without stopping (those resting on a drawing not checked)."""
        return [] if drawing else [f for f in self.findings if f.drawing]


def _unit_name(factor: float) -> str | None:
    for k, name in UNITS.items():
        if abs(factor / k - 1.0) <= UNIT_MATCH:
            return name
    return None


def _system(P: np.ndarray, R: np.ndarray, rho: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The free-pose form with the reading's scale free: (N, 18) and (N,) (module docstring)."""
    n = len(P)
    rtp = np.einsum("nji,nj->ni", R, P)  # Rᵀ P
    cols = [2.0 * rtp, -2.0 * P, -2.0 * R.reshape(n, 9), np.ones((n, 1))]
    cols += [-(rho**2)[:, None], -2.0 * rho[:, None]]
    return np.concatenate(cols, axis=1), -np.einsum("ni,ni->n", P, P)


def _solve(a_mat: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least squares with unit-norm columns: (solution, its covariance per unit variance,
    whether every direction is determined), for one system (N, n), (N,) or a stack of them
    (…, N, n), (…, N): one batched SVD rather than a Python loop over the systems."""
    norm = np.linalg.norm(a_mat, axis=-2)
    norm = np.where(norm == 0.0, 1.0, norm)
    u, sv, vt = np.linalg.svd(a_mat / norm[..., None, :], full_matrices=False)
    keep = sv > sv[..., :1] * 1e-12
    inv = np.where(keep, 1.0 / np.where(keep, sv, 1.0), 0.0)
    uty = np.einsum("...mk,...m->...k", u, y)
    coef = np.einsum("...ki,...k->...i", vt, uty * inv) / norm
    cov = np.einsum("...ki,...k,...kj->...ij", vt, inv**2, vt) / (
        norm[..., :, None] * norm[..., None, :]
    )
    return coef, cov, np.asarray(keep.all(axis=-1))


def _residual_mm(a_mat: np.ndarray, y: np.ndarray, coef: np.ndarray, rho: np.ndarray):
    """The form's residual in mm (it is in mm²: divided by twice the length) and the length,
    for a solution (n,) of a system (N, n), or stacks of them (…, n), (…, N, n) broadcast
    (then each row of the result is one solution's)."""
    s = np.sqrt(np.abs(coef[..., 16]))
    with np.errstate(divide="ignore", invalid="ignore"):
        length = s[..., None] * rho + np.where(s > 0, coef[..., 17] / s, np.nan)[..., None]
        return (np.einsum("...mn,...n->...m", a_mat, coef) - y) / (2.0 * np.abs(length)), length


#: Poses whose residual lies beyond this many robust standard deviations (1.4826 MAD) are
#: left out and the leg solved again (a typo, a pose taken mid-move: the outlier screen names
#: them), at most :data:`TRIM_ROUNDS` times and never more than :data:`TRIM_SHARE` of them.
TRIM_SIGMAS = 8.0
TRIM_ROUNDS = 4
TRIM_SHARE = 0.2
#: Random subsets tried for a start that no outlier has thrown off.
SUBSETS = 12


def _trimmed(a_mats: np.ndarray, y: np.ndarray, rho: np.ndarray):
    """The poses each leg is judged on: all but its gross outliers. ``a_mats`` (L, N, n) the
    legs' systems, ``y`` (N,) their common right side, ``rho`` (L, N) mm their readings.
    Returns (kept (L, N) bool, and each leg's fit on every pose: :func:`_solve`'s three, each
    with the legs first), the fit most legs keep.

    A least-squares start is thrown far off by one pose 300 mm wrong, so the start is the best
    (smallest median residual) of the fit on every pose and of fits on random subsets, one of
    which holds no outlier when few poses are bad (least median of squares); poses far from it
    are then left out, round by round. Every leg's starts are solved at once (one batched SVD)."""
    legs, n = rho.shape
    rng = np.random.default_rng(0)  # the same poses judged the same way every time
    size = min(n, max(3 * a_mats.shape[-1], n // 5))
    subsets = np.array([rng.choice(n, size, replace=False) for _ in range(SUBSETS)])
    full = _solve(a_mats, y)
    coefs = np.concatenate([full[0][:, None], _solve(a_mats[:, subsets], y[subsets])[0]], axis=1)
    residuals, _ = _residual_mm(a_mats[:, None], y, coefs, rho[:, None])  # (L, starts, N)
    finite = np.all(np.isfinite(residuals), axis=-1)
    medians = np.where(finite, np.median(np.abs(residuals), axis=-1), np.inf)
    kept = np.ones((legs, n), bool)
    for leg in range(legs):
        best = int(np.argmin(medians[leg]))
        res = residuals[leg, best] if np.isfinite(medians[leg, best]) else None
        kept[leg] = _trim(a_mats[leg], y, rho[leg], res)
    return kept, full


def _trim(a_mat: np.ndarray, y: np.ndarray, rho: np.ndarray, res: np.ndarray | None):
    """One leg's poses (N,) bool less those far from its best start's residual ``res``."""
    n = len(y)
    use = np.ones(n, bool)
    for _ in range(TRIM_ROUNDS):
        if res is None or not np.all(np.isfinite(res)):
            return use
        centre = np.median(res)
        spread = 1.4826 * np.median(np.abs(res - centre))
        new = np.abs(res - centre) <= max(TRIM_SIGMAS * spread, 1e-6)
        if new.sum() < (1.0 - TRIM_SHARE) * n or np.array_equal(new, use):
            return use
        use = new
        coef, _, _ = _solve(a_mat[use], y[use])
        res, _ = _residual_mm(a_mat, y, coef, rho)
    return use


def _unit_factor(factor: float) -> float:
    """The known factor (:data:`UNITS`) ``factor`` is near."""
    return min(UNITS, key=lambda k: abs(factor / k - 1.0))


def _leg_fit(a_all: np.ndarray, y_all: np.ndarray, rho: np.ndarray, leg: int, use, full):
    """The free-pose form with the reading's scale free (see the module docstring): the leg's
    system (N, 18), (N,), its readings (N,) mm, solved on its poses ``use`` (N,) (all but its
    gross outliers); ``full``: its solution on every pose (:func:`_solve`'s three)."""
    a_mat, y = a_all[use], y_all[use]
    coef, cov, determined = full if use.all() else _solve(a_mat, y)
    res_mm, length = _residual_mm(a_mat, y, coef, rho[use])
    s2, s_delta = float(coef[16]), float(coef[17])
    s = float(np.sqrt(abs(s2)))
    delta = s_delta / s if s > 0 else float("nan")
    sign = 1.0 if np.median(length) >= 0 else -1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        rms = float(np.sqrt(np.mean(res_mm**2)))
        res = a_mat @ coef - y
        sigma2 = float(res @ res) / max(len(y) - a_mat.shape[1], 1)
        # σ of s² from the residual, then of s (ds = ds² / 2s).
        scale_sigma = float(np.sqrt(sigma2 * cov[16, 16]) / (2.0 * s)) if determined else np.nan
        points = np.sqrt(sigma2 * np.diag(cov)[:6])
        points_sigma = float(points.max()) if determined else float("nan")
    return LegSignature(
        leg, sign * s, scale_sigma, sign * delta, rms, coef[3:6], coef[:3], points_sigma, use
    )


def _rotations(quaternion: np.ndarray, order: str) -> np.ndarray:
    q = quaternion if order == "wxyz" else quaternion[:, [3, 0, 1, 2]]
    return Rotation.from_quat(q, scalar_first=True).as_matrix()


def signatures(meas, order: str = "wxyz") -> list[LegSignature]:
    """Each leg's signature with the quaternions read in ``order`` (``wxyz`` as the table
    says, or ``xyzw``: the columns qw, qx, qy, qz hold x, y, z, w)."""
    R = _rotations(meas.quaternion, order)
    systems = [_system(meas.position, R, meas.readings[:, k]) for k in range(6)]
    a_mats, y, rho = np.stack([a for a, _ in systems]), systems[0][1], meas.readings.T
    kept, full = _trimmed(a_mats, y, rho)
    return [
        _leg_fit(a_mats[k], y, rho[k], k + 1, kept[k], tuple(f[k] for f in full)) for k in range(6)
    ]


def _total_rms(legs: list[LegSignature]) -> float:
    values = np.array([leg.rms_mm for leg in legs])
    return float(np.sqrt(np.mean(values**2))) if np.all(np.isfinite(values)) else float("inf")


def check_consistency(
    meas, design: Robot, tolerance: float = DRAWING_TOLERANCE, source: str = "the table"
) -> Consistency:
    """The data's consistency with themselves and with the drawing ``design`` (see the module
    docstring); ``tolerance`` is the drawing check's, ``source`` names the table in messages."""
    n = len(meas)
    if n < MIN_POSES:
        return Consistency(False, note=f"{n} poses: too few to check the data's consistency")
    meas = _Rows.spread(meas)
    by_order = {"wxyz": signatures(meas, "wxyz")}
    orders = {"wxyz": _total_rms(by_order["wxyz"])}
    # The other order is read only where it could be taken: the order as read misfits.
    if orders["wxyz"] > ORDER_MIN_MM:
        by_order["xyzw"] = signatures(meas, "xyzw")
        orders["xyzw"] = _total_rms(by_order["xyzw"])
    out = Consistency(True, orders)
    if "xyzw" in orders and orders["wxyz"] > ORDER_RATIO * orders["xyzw"]:
        ratio = orders["wxyz"] / orders["xyzw"]
        out.findings.append(
            Finding(
                "quaternion-order",
                (),
                f"{source}: the quaternions look scalar-last (x, y, z, w) in the columns qw, qx, "
                f"qy, qz: read that way, the tracker's poses and the readings agree {ratio:.0f}× "
                f"better (leg-length RMS {orders['xyzw']:.3g} mm against {orders['wxyz']:.3g} "
                "mm). hexcal's table is scalar first: move the w column to qw (hexcal import "
                'does it with quaternion_order = "xyzw" in its map)',
                False,
                ratio,
            )
        )
        out.order = "xyzw"
    out.legs = by_order[out.order]
    out.findings += _reading_findings(out.legs, source)
    if not out.findings:
        out.findings += _drawing_findings(out.legs, design, tolerance, source)
    if not out.findings and "leg_offsets" in design.model_fields_set:
        R = _rotations(meas.quaternion, out.order)
        offsets = []
        for k, leg in enumerate(out.legs):
            use = leg.kept  # the poses its signature was judged on: the same system
            rho = meas.readings[:, k]
            offsets.append(free_linear(meas.position[use], R[use], rho[use])[2])
        out.findings += offset_findings(np.array(offsets), design, tolerance, source)
    return out


def _reading_findings(legs: list[LegSignature], source: str) -> list[Finding]:
    """Readings that run backwards or in another unit than the tracker's positions."""
    out = []
    lo, hi = SCALE_RANGE
    determined = [g for g in legs if np.isfinite(g.scale) and g.scale_sigma < 0.1 * abs(g.scale)]
    flipped = [g for g in determined if g.scale < 0 and lo <= -g.scale <= hi]
    if flipped:
        names = ", ".join(f"rho{g.leg}" for g in flipped)
        out.append(
            Finding(
                "sign",
                tuple(g.leg for g in flipped),
                f"{source}: {'leg' if len(flipped) == 1 else 'legs'} "
                f"{', '.join(str(g.leg) for g in flipped)}: the reading falls as the leg "
                f"lengthens (scale {', '.join(f'{g.scale:+.3f}' for g in flipped)} against the "
                f"tracker; +1 expected): a sign flipped in the encoder's set-up or the log. "
                f"Negate {names} (or set sign = -1 for the leg in rig.toml) and calibrate again",
                False,
                2.0,
            )
        )
    scaled = [g for g in determined if not lo <= abs(g.scale) <= hi]
    if scaled:
        factors = [abs(g.scale) for g in scaled]
        unit = _unit_name(float(np.median(factors)))
        inverse = _unit_name(1.0 / float(np.median(factors)))
        if unit:
            guess = f"readings in {unit} against positions in mm? Convert the readings to mm"
        elif inverse:
            guess = (
                f"positions in {inverse} against readings in mm (or readings in 1/"
                f"{1.0 / float(np.median(factors)):.3g} mm units)? Convert both to mm"
            )
        else:
            guess = (
                "readings in another unit than the positions (encoder counts, revolutions?): "
                "convert them to mm (hexcal import's map takes mm_per_unit)"
            )
        legs_text = ", ".join(f"leg {g.leg} ×{abs(g.scale):.4g}" for g in scaled)
        out.append(
            Finding(
                "units",
                tuple(g.leg for g in scaled),
                f"{source}: the lengths the tracker implies change {legs_text} as fast as the "
                f"readings (1 expected): {guess}",
                False,
                float(max(max(factors), 1.0 / min(factors))),
            )
        )
    return out


def _geometry_scale(legs: list[LegSignature], design: Robot) -> float:
    """How many times the drawing's size the data's geometry is (RMS radius of a and of b)."""
    a = np.array([g.a for g in legs])
    b = np.array([g.b for g in legs])

    def radius(p: np.ndarray) -> float:
        return float(np.sqrt(np.mean(np.sum((p - p.mean(axis=0)) ** 2, axis=1))))

    ka = radius(a) / max(radius(design.a), 1e-9)
    kb = radius(b) / max(radius(design.b), 1e-9)
    return float(np.sqrt(ka * kb)) if ka > 0 and kb > 0 else float("nan")


def geometry_scale_finding(k: float, source: str) -> Finding | None:
    """The finding for a geometry ``k`` times the drawing's, None when ``k`` is plausible."""
    lo, hi = GEOMETRY_SCALE_RANGE
    if not np.isfinite(k) or lo <= k <= hi or k <= 0:
        return None
    if k > 1:
        unit = _unit_name(k)
        shown = _unit_factor(k) if unit else k
        guess = (
            f"is robot.json in {unit}? hexcal reads mm: multiply its points and offsets by "
            f"{shown:.4g}"
            if unit
            else "is robot.json in another unit, or for another robot?"
        )
        text = (
            f"robot.json looks {shown:.4g}× too small for the data (the joints the poses imply "
            f"lie {k:.3g}× farther apart than the drawing's): {guess}"
        )
    else:
        unit = _unit_name(1.0 / k)
        shown = _unit_factor(1.0 / k) if unit else 1.0 / k
        guess = (
            f"are the table's positions and readings in {unit}? hexcal reads mm: convert both"
            if unit
            else "are the table's positions and readings in another unit than the drawing?"
        )
        text = (
            f"the data's geometry is {shown:.4g}× smaller than the drawing's (robot.json; "
            f"{1.0 / k:.3g}× as measured): {guess}"
        )
    return Finding("geometry-scale", (), f"{source}: {text}", True, max(k, 1.0 / k))


def _design_lengths(design: Robot) -> np.ndarray:
    """(6,) mm: the legs' lengths at the drawing's home pose."""
    rot = Rotation.from_quat(design.home.quaternion, scalar_first=True).as_matrix()
    p = np.asarray(design.home.position, float)
    return np.linalg.norm(p + design.b @ rot.T - design.a, axis=1)


def _drawing_findings(
    legs: list[LegSignature], design: Robot, tolerance: float, source: str
) -> list[Finding]:
    """The data's geometry against the drawing: its size, and which leg each column is. Not
    judged (an empty list) when the poses do not determine the joints well (too little
    rotation): their size to a tenth of the data's own, their places to a tenth of the
    drawing's tolerance."""
    sigma = max(g.points_sigma_mm for g in legs)
    a_fit = np.array([g.a for g in legs])
    size = float(np.linalg.norm(a_fit - a_fit.mean(axis=0), axis=1).mean())
    if not sigma <= POINTS_SIGMA_FRACTION * size:
        return []
    scale = geometry_scale_finding(_geometry_scale(legs, design), source)
    if scale is not None:
        return [scale]
    tol_a, tol_b = drawing_tolerances(design, tolerance)
    if not sigma <= POINTS_SIGMA_FRACTION * min(tol_a, tol_b):
        return []
    a = np.array([g.a for g in legs])
    b = np.array([g.b for g in legs])
    # The free form's points are good to tenths of a mm, not to the tolerance's edge: a leg
    # merely beyond it is the fitted geometry's to judge, after the fit; one far beyond it, or
    # at another leg's place, is flagged now.
    near = [f for f in check_against_drawing(a, b, design, tolerance) if f.kind != "far"]
    far = [
        f for f in check_against_drawing(a, b, design, tolerance * FAR_FACTOR) if f.kind == "far"
    ]
    return [
        Finding(f.kind, f.legs, f"{source}: " + f.text.replace(" fitted ", " implied "), True, 2.0)
        for f in near + far
    ]


def offset_findings(
    offsets: np.ndarray, design: Robot, tolerance: float, source: str
) -> list[Finding]:
    """Leg offsets (6,) mm, as Model 42 fits them (reading scale 1), far from robot.json's:
    beyond ``tolerance`` of a leg's length at the drawing's home pose."""
    tol = tolerance * float(np.mean(_design_lengths(design)))
    out = []
    for k, off in enumerate(offsets.tolist()):
        gap = off - float(design.offsets[k])
        if abs(gap) > tol:
            out.append(
                Finding(
                    "offset",
                    (k + 1,),
                    f"{source}: leg {k + 1}'s offset is {off:.1f} mm by the data but "
                    f"{design.offsets[k]:.1f} mm in robot.json ({gap:+.1f} mm; tolerance "
                    f"{tol:.1f} mm, {tolerance:g} of a leg's length): a wrong leg_offsets entry, "
                    "or a reading zeroed elsewhere (homed again, another zero_mm)",
                    True,
                    abs(gap) / tol,
                )
            )
    return out


def likely_causes(meas, design: Robot, tolerance: float = DRAWING_TOLERANCE) -> list[str]:
    """The likely causes of a fit that did not converge or diverged, most likely first, from
    the data's own signature: every finding of :func:`check_consistency`, ranked by how
    clearly the data show it, then the weaker signs (a reading scale off by more than the
    gain effect allows, the other quaternion order fitting better at all)."""
    c = check_consistency(meas, design, tolerance)
    if not c.checked:
        return []
    ranked = sorted(c.findings, key=lambda f: -f.strength)
    causes = [f.text.split(": ", 1)[1] for f in ranked]
    xyzw = c.orders.get("xyzw")
    if xyzw is None:  # not read by the check: the order as read fitted well
        xyzw = _total_rms(signatures(_Rows.spread(meas), "xyzw"))
    if not any(f.cause == "quaternion-order" for f in ranked) and xyzw < c.orders["wxyz"]:
        causes.append(
            f"the quaternion order: scalar last fits a little better ({xyzw:.3g} mm "
            f"against {c.orders['wxyz']:.3g} mm)"
        )
    off_gain = [g for g in c.legs if abs(abs(g.scale) - 1.0) > 0.1 and np.isfinite(g.scale)]
    if off_gain and not any(f.cause in ("units", "sign") for f in ranked):
        causes.append(
            "a reading's scale: "
            + ", ".join(f"leg {g.leg} ×{g.scale:.3g}" for g in off_gain)
            + " (1 expected; the gain effect allows ±10 %)"
        )
    return causes
