"""A calibrated robot as a predictor: readings → pose and pose → readings, effects included.

The model is the one the fit uses: the geometric length of leg k, ``|P + R b_k − a_k|``, equals
``ρ_k + offset_k + Σ basis(data) @ θ`` — the reading, its offset and every catalogue effect
(gain, backlash with the motion history, thermal with the temperature, compliance with the leg
forces at the pose, lead screw). So:

- **readings → pose** (what the platform does when the encoders read ρ): the pose whose legs have
  those lengths. The effects that depend on the pose (compliance) are re-evaluated at each
  Newton step, so the pose and its predicted lengths agree.
- **pose → readings** (what the encoders must read for a wanted pose: the compensation a
  controller applies): the readings that, with their own effects (a gain scales the reading, the
  backlash state follows the readings' motion), give the pose's lengths.

Both take poses in recording / motion order: backlash depends on the direction each leg last
moved, so the first pose of a sequence has no known direction (its backlash term is 0) until a
leg moves by more than the dead band.

Limits: readings outside ``leg_range_mm`` (the stroke, on readings), lengths no pose closes (out
of the workspace) and legs beyond ``joint_limit_deg`` (each joint's cone about the leg's
direction at home) are refused with the row named (:class:`PredictionError`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.effects import EffectData, ParamSpec, get_effect
from hexcal.errors import InputError
from hexcal.model.batched import solve_columns as batched_solve_columns
from hexcal.model.kinematics import ForwardKinematicsError, forward_kinematics
from hexcal.model.robot import Robot

#: Newton steps stop when every leg closes to this, mm.
CLOSE_MM = 1e-10
#: A pose is refused when its legs do not close to this after the iterations, mm.
REFUSE_MM = 1e-7
#: Rows the batched Newton leaves open that are each solved again from restarts; beyond
#: this many (and half the rows) the model is taken not to fit the readings.
MAX_RESCUED = 10
MAX_NEWTON = 60
#: Fixed-point iterations of pose → readings (each contracts by the effects' slope, e.g. a gain).
MAX_FIXED_POINT = 400


class PredictionError(InputError):
    """A reading or pose the model cannot serve: out of the stroke, the workspace or a joint's
    range; the message names the rows (1-based, in the order given) and what to do."""


@dataclass(frozen=True)
class Poses:
    """Platform poses: ``position`` (N, 3) mm and ``rotation`` (N, 3, 3), measurement frame."""

    position: np.ndarray
    rotation: np.ndarray

    @property
    def quaternion(self) -> np.ndarray:
        """(N, 4) unit quaternions, scalar first, qw ≥ 0."""
        q = Rotation.from_matrix(self.rotation).as_quat(scalar_first=True)
        return q * np.where(q[:, :1] < 0, -1.0, 1.0)


@dataclass(frozen=True)
class LegModel:
    """A robot's geometry (``robot``: a, b, offsets and its other keys) with catalogue
    ``effects`` (``offset`` excluded: the offsets are the robot's) and their ``values`` (q,) in
    their spec units (ppm, mm, ppm/K, µm/N), in the effects' parameter order."""

    robot: Robot
    effects: tuple[str, ...] = ()
    values: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: The measurement table's extra numeric columns, (N,) each, for effects that follow a
    #: lab's own sensor (:func:`hexcal.effects.covariates.numeric_columns`); given with the
    #: table whose rows are solved (:meth:`with_columns`)
    columns: dict = field(default_factory=dict, compare=False)

    def with_columns(self, columns: dict) -> LegModel:
        """The same model reading the table's extra numeric columns ``columns``."""
        return replace(self, columns=dict(columns))

    def __post_init__(self) -> None:
        object.__setattr__(self, "effects", tuple(e for e in self.effects if e != "offset"))
        object.__setattr__(self, "values", np.asarray(self.values, float).reshape(-1))
        n = len(self.specs)
        if self.values.shape != (n,):
            raise ValueError(
                f"the model's effects ({', '.join(self.effects) or 'none'}) take {n} parameter "
                f"values, got {self.values.size}"
            )

    @property
    def specs(self) -> list[ParamSpec]:
        return [s for e in self.effects for s in get_effect(e).params(self.robot)]

    @property
    def name(self) -> str:
        """e.g. ``"+ gain + backlash"``: the effects beyond the geometry (empty without)."""
        return "".join(f" + {e}" for e in self.effects)

    # -- lengths -------------------------------------------------------------------------------
    def data(
        self,
        readings: np.ndarray,
        position: np.ndarray,
        rotation: np.ndarray,
        t: np.ndarray | None = None,
        temperature: np.ndarray | None = None,
    ) -> EffectData:
        """The effects' inputs for N poses at this model's geometry."""
        readings = np.asarray(readings, float)
        n = len(readings)
        t = np.arange(n, dtype=float) if t is None else np.asarray(t, float)
        temp = None if temperature is None else np.asarray(temperature, float)
        r = self.robot
        cols = {k: v for k, v in self.columns.items() if len(v) == n}
        return EffectData(
            readings, np.asarray(position, float), rotation, t, temp, r, r.a, r.b, columns=cols
        )

    def effect_lengths(self, data: EffectData) -> np.ndarray:
        """(N, 6) mm the effects add to ``reading + offset``."""
        if not self.effects:
            return np.zeros_like(data.readings)
        for e in self.effects:
            why = get_effect(e).cannot_predict(data)
            if why:
                raise PredictionError(f"the model includes {e}: {why}")
        basis = np.concatenate([get_effect(e).basis(data) for e in self.effects], axis=-1)
        return basis @ self.values

    def lengths(
        self,
        readings: np.ndarray,
        position: np.ndarray,
        rotation: np.ndarray,
        t: np.ndarray | None = None,
        temperature: np.ndarray | None = None,
    ) -> np.ndarray:
        """(N, 6) mm: the legs' geometric lengths the model infers from the readings (N, 6) mm
        at poses (N, 3) mm, (N, 3, 3) (the pose matters only to pose-dependent effects)."""
        data = self.data(readings, position, rotation, t, temperature)
        return data.readings + self.robot.offsets + self.effect_lengths(data)

    def geometric(self, position: np.ndarray, rotation: np.ndarray) -> np.ndarray:
        """(N, 6) mm ``|P + R b_k − a_k|`` at this model's geometry."""
        v = _leg_vectors(self.robot.a, self.robot.b, position, rotation)
        return np.linalg.norm(v, axis=-1)

    def residuals(self, meas) -> np.ndarray:
        """(N, 6) mm on a measurement table: the length the readings say (reading + offset +
        effects) − the length of the measured pose; the fit's ``residuals`` convention."""
        rot = meas.rotations.as_matrix()
        lengths = self.lengths(meas.readings, meas.position, rot, meas.t, meas.temperature)
        return lengths - self.geometric(meas.position, rot)

    # -- readings → pose -----------------------------------------------------------------------
    def poses(
        self,
        readings: np.ndarray,
        t: np.ndarray | None = None,
        temperature: np.ndarray | None = None,
        guess: Poses | None = None,
        check_limits: bool = True,
    ) -> Poses:
        """The platform poses (N) that readings (N, 6) mm, in motion order, put it in.

        ``guess``: poses to start from (the tracker's, when comparing with it); default the
        robot's home. Raises :class:`PredictionError` naming the rows out of the stroke, the
        workspace or a joint's range."""
        readings = np.atleast_2d(np.asarray(readings, float))
        if check_limits:
            self._check_stroke(readings, "readings")
        out, closed = self.solve_poses(readings, t, temperature, guess)
        if not closed.all():
            rows = np.where(~closed)[0]
            raise PredictionError(
                f"readings of {_rows(rows)} are outside the workspace: no pose of the platform "
                "gives those six lengths; check the readings (units, leg order) and the model"
            )
        if check_limits:
            self._check_joints(out, "readings")
        return out

    def solve_poses(
        self,
        readings: np.ndarray,
        t: np.ndarray | None = None,
        temperature: np.ndarray | None = None,
        guess: Poses | None = None,
        rows: np.ndarray | None = None,
    ) -> tuple[Poses, np.ndarray]:
        """Like :meth:`poses` without refusing: (poses, closed (N,) bool) — a row whose legs
        do not close (out of the workspace) is left at its best attempt. ``rows``: solve these
        rows only (indices into the table, which the effects see whole, in order); then both
        are of those rows."""
        readings = np.atleast_2d(np.asarray(readings, float))
        n = len(readings)
        if guess is None:
            guess = self.home(n)
        todo = np.arange(n) if rows is None else np.asarray(rows, int)
        P, R = _newton(self, readings, t, temperature, guess.position, guess.rotation, todo)
        err = self._closure(readings, t, temperature, P, R, todo)
        bad = todo[~(err < REFUSE_MM)]
        if len(bad) > max(MAX_RESCUED, len(todo) // 2):
            # Most rows do not close: the model does not fit these readings (a wrong file, a
            # broken model), and restarting each row would only take long to say so.
            return Poses(P[todo], R[todo]), err < REFUSE_MM
        # Newton from a poor guess may stall or reach another assembly mode: the library
        # solver with restarts gives a better start for those rows.
        for i in bad:
            lengths = self.lengths(readings, P, R, t, temperature)[i]
            try:
                p, rot = forward_kinematics(
                    self.robot.a,
                    self.robot.b,
                    lengths,
                    guess.position[i],
                    Rotation.from_matrix(guess.rotation[i]),
                )
            except ForwardKinematicsError:
                continue
            P[i], R[i] = p, rot.as_matrix()
        if len(bad):
            P, R = _newton(self, readings, t, temperature, P, R, todo)
            err = self._closure(readings, t, temperature, P, R, todo)
        return Poses(P[todo], R[todo]), err < REFUSE_MM

    def _closure(self, readings, t, temperature, P, R, rows) -> np.ndarray:
        """(n,) mm: each of ``rows``' largest leg mismatch, geometric against the model's."""
        if self.effects:
            lengths = self.lengths(readings, P, R, t, temperature)[rows]
        else:
            lengths = readings[rows] + self.robot.offsets
        return np.max(np.abs(self.geometric(P[rows], R[rows]) - lengths), axis=1)

    def home(self, n: int = 1) -> Poses:
        """The robot's home pose, repeated n times."""
        h = self.robot.home
        rot = Rotation.from_quat(h.quaternion, scalar_first=True).as_matrix()
        return Poses(np.tile(h.position, (n, 1)), np.tile(rot, (n, 1, 1)))

    # -- pose → readings -----------------------------------------------------------------------
    def readings(
        self,
        position: np.ndarray,
        rotation: np.ndarray,
        t: np.ndarray | None = None,
        temperature: np.ndarray | None = None,
        check_limits: bool = True,
    ) -> np.ndarray:
        """(N, 6) mm: what the encoders must read for the platform to be at the poses
        (N, 3) mm, (N, 3, 3), in motion order — the compensation a controller applies."""
        P = np.atleast_2d(np.asarray(position, float))
        R = np.asarray(rotation, float).reshape(-1, 3, 3)
        if check_limits:
            self._check_joints(Poses(P, R), "poses")
        target = self.geometric(P, R)
        rho = target - self.robot.offsets
        for _ in range(MAX_FIXED_POINT):
            extra = self.effect_lengths(self.data(rho, P, R, t, temperature))
            new = target - self.robot.offsets - extra
            step = np.max(np.abs(new - rho)) if len(rho) else 0.0
            rho = new
            if step < CLOSE_MM:
                break
        else:
            raise PredictionError(
                "the readings for these poses did not settle (a leg's move sits at the backlash "
                "dead band, or an effect's slope is near 1); give the poses in motion order with "
                "clear moves between them"
            )
        if check_limits:
            self._check_stroke(rho, "poses")
        return rho

    # -- limits --------------------------------------------------------------------------------
    def _check_stroke(self, readings: np.ndarray, what: str) -> None:
        rng = self.robot.leg_range_mm
        if rng is None:
            return
        lo, hi = rng
        out = (readings < lo) | (readings > hi)
        if out.any():
            rows, legs = np.where(out)
            i, k = rows[0], legs[0]
            raise PredictionError(
                f"{what}: {_rows(np.unique(rows))} put a leg beyond its stroke (leg_range_mm "
                f"[{lo:g}, {hi:g}] mm on readings; first: leg {k + 1} reads "
                f"{readings[i, k]:.4f} mm); choose poses within the stroke"
            )

    def joint_angles(self, poses: Poses) -> tuple[np.ndarray, np.ndarray]:
        """(N, 6) deg each: the angle of every leg at its base joint and at its platform joint
        from the leg's direction at home (the joints' neutral axis)."""
        home = self.home(1)
        v0 = _leg_vectors(self.robot.a, self.robot.b, home.position, home.rotation)[0]
        u0 = v0 / np.linalg.norm(v0, axis=-1, keepdims=True)
        u0_platform = np.einsum("ji,kj->ki", home.rotation[0], u0)
        v = _leg_vectors(self.robot.a, self.robot.b, poses.position, poses.rotation)
        u = v / np.linalg.norm(v, axis=-1, keepdims=True)
        u_platform = np.einsum("nji,nkj->nki", poses.rotation, u)
        base = np.degrees(np.arccos(np.clip(np.einsum("nki,ki->nk", u, u0), -1, 1)))
        plat = np.degrees(
            np.arccos(np.clip(np.einsum("nki,ki->nk", u_platform, u0_platform), -1, 1))
        )
        return base, plat

    def _check_joints(self, poses: Poses, what: str) -> None:
        limit = getattr(self.robot, "joint_limit_deg", None)
        if limit is None:
            return
        base, plat = self.joint_angles(poses)
        worst = np.maximum(base, plat)
        out = worst > limit
        if out.any():
            rows, legs = np.where(out)
            i, k = rows[0], legs[0]
            raise PredictionError(
                f"{what}: {_rows(np.unique(rows))} put a joint beyond its range (joint_limit_deg "
                f"{limit:g}°; first: leg {k + 1} at {worst[i, k]:.1f}° from its direction at "
                "home); choose poses nearer home"
            )


def _rows(rows: np.ndarray) -> str:
    shown = ", ".join(str(int(r) + 1) for r in rows[:10])
    more = f" and {len(rows) - 10} more" if len(rows) > 10 else ""
    return ("row " if len(rows) == 1 else "rows ") + shown + more


def _leg_vectors(a, b, position, rotation) -> np.ndarray:
    """(N, 6, 3) mm ``P + R b_k − a_k``."""
    P = np.atleast_2d(np.asarray(position, float))
    R = np.asarray(rotation, float).reshape(-1, 3, 3)
    return np.swapaxes(R @ b.T, -1, -2) + (P[:, None, :] - a[None])


def _newton(
    model: LegModel, readings, t, temperature, P0, R0, rows: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Batched Newton on the six leg lengths of every pose at once (an N-pose table solves in
    a few vectorised steps rather than N library calls), or of the poses ``rows`` only (the
    others stay at P0, R0). The model's lengths are re-evaluated at each step, over the whole
    table, so pose-dependent effects (compliance) converge with the pose; without effects they
    are the readings plus the offsets, evaluated once, and the poses that have converged
    leave the batch."""
    a, b = model.robot.a, model.robot.b
    P = np.array(P0, float).reshape(-1, 3).copy()
    R = np.array(R0, float).reshape(-1, 3, 3).copy()
    todo = np.arange(len(P)) if rows is None else np.asarray(rows, int)
    fixed = None
    if not model.effects:
        fixed = np.asarray(readings, float)[todo] + model.robot.offsets
    # The poses being solved, pose axis last: p (3, n), r (3, 3, n).
    p, r = np.ascontiguousarray(P[todo].T), np.ascontiguousarray(R[todo].transpose(1, 2, 0))
    for _ in range(MAX_NEWTON):
        if fixed is None:
            P[todo], R[todo] = p.T, r.transpose(2, 0, 1)
            lengths = model.lengths(readings, P, R, t, temperature)[todo].T
        else:
            lengths = fixed.T
        rb = [b @ r[i] for i in range(3)]  # (R b_k)_i, (6, n) each
        v = [rb[i] + (p[i] - a[:, i, None]) for i in range(3)]
        norm = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        f = norm - lengths  # (6, n)
        active = np.max(np.abs(f), axis=0) >= CLOSE_MM
        if not active.any():
            break
        if fixed is not None and not active.all():
            # The lengths do not move: converged poses leave the batch.
            P[todo[~active]], R[todo[~active]] = p[:, ~active].T, r[..., ~active].transpose(2, 0, 1)
            todo, fixed, p, r = todo[active], fixed[active], p[:, active], r[..., active]
            f, norm = f[:, active], norm[:, active]
            rb, v = [c[:, active] for c in rb], [c[:, active] for c in v]
            active = np.ones(len(todo), bool)
        n = [c / norm for c in v]
        # Row k of the Jacobian: [n_k, (R b_k) × n_k]; here by columns.
        cols = [
            *n,
            rb[1] * n[2] - rb[2] * n[1],
            rb[2] * n[0] - rb[0] * n[2],
            rb[0] * n[1] - rb[1] * n[0],
        ]
        step, _ = batched_solve_columns(cols, -f)
        step[:, ~active] = 0.0
        # Damp steps that would jump across the workspace (a poor guess): Newton then stays in
        # the guess's assembly mode.
        size = np.sqrt(np.sum(step[:3] ** 2, axis=0)) / 50.0 + np.sqrt(
            np.sum(step[3:] ** 2, axis=0)
        )
        step *= np.minimum(1.0, 1.0 / np.maximum(size, 1e-300))
        p += step[:3]
        turn = Rotation.from_rotvec(step[3:].T).as_matrix()  # (n, 3, 3)
        r = np.einsum("nij,jkn->ikn", turn, r)
    P[todo], R[todo] = p.T, r.transpose(2, 0, 1)
    return P, R
