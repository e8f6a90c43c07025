"""Poses that decide: the reachable poses that best tell two hypotheses apart, or best resolve
one effect, given the fit so far (``hexcal plan``).

Effects are linear in their parameters, so what N more poses would show is known before they
are recorded, to first order at the fitted geometry. Each hypothesis is a model — the geometry,
the effects already in the model, and its own effect (:data:`GEOMETRY`: none) — fitted to the
session; its fitted contribution is a column of whitened leg lengths over any poses.

- To separate A from B: whichever is true, the other leaves χ² beyond the noise by the
  noncentrality of the true one's contribution once the other's columns are projected out
  (:func:`hexcal.diagnosis.selection.schur_after`); the poses are picked to maximise the
  smaller of the two (the geometry alone has no contribution: against it, only the effect's
  counts). What they are then expected to show is the Δχ²'s own distribution given the
  session (:func:`hexcal.diagnosis.selection.predicted_delta_chi2`: its mean, unbiased, and
  standard deviation), and they decide where that, two standard deviations short, pays the
  verdict's margins and Vuong's test would also put the two apart
  (:func:`~hexcal.diagnosis.selection.predicted_vuong_z`).
- To resolve one effect: D-optimal — the log-determinant of its parameters' information once
  the geometry's and the model's other columns are projected out.

Poses are picked greedily from a large set of reachable free poses
(:mod:`hexcal.diagnosis.plan_pool`: random ones within the session's own box and tilt about
home, and as many on that region's edge), each candidate's gain computed for all at once.
Clamped poses are not planned: a plan is free poses.

A plan is a schedule too (:class:`When`): the new poses follow the session at its median pace,
after a wait the plan chooses where the time separates the hypotheses (a drift goes on while
the temperature holds; up to the session's own span), at the session's last temperature held —
or at one the lab states, or, where the lab can hold a range, at the one the plan chooses,
reached no faster than the session's own temperature changed (:func:`_schedule`). The table's
t and temperature columns say when and at what temperature to record each pose.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.diagnosis import selection
from hexcal.diagnosis.plan_pool import (
    BATCH,
    _candidates,
    _with_edges,
)
from hexcal.effects import EffectData, get_effect
from hexcal.estimate.effect_fit import ModelFit, Problem, fit_model, fitted_robot
from hexcal.estimate.leg_rows import pose_jacobian
from hexcal.estimate.predict import LegModel
from hexcal.io.measurements import Measurements
from hexcal.model.noise import DEFAULT_SIGMAS, leg_whiteners
from hexcal.model.robot import Robot

#: The hypothesis "no further effect": the model as it is.
GEOMETRY = "geometry"
#: Random reachable poses the plan picks from.
N_CANDIDATES = 2000
#: Random draws averaged for the random poses' separation.
N_RANDOM = 20
#: At most this many times the plan's poses are tried as random ones to match its separation.
MATCH_LIMIT = 64


@dataclass
class Plan:
    """The planned poses and what they are expected to show.

    ``meas``: the poses as a measurement table (free poses, step ``plan``, the readings the
    fitted model predicts at each, mm); ``planned``, ``random``: the criterion with these N
    poses added and with N random reachable ones (mean of :data:`N_RANDOM`, recorded on the
    plan's schedule) — to separate, the expected Δχ² between the hypotheses (the predictive
    mean, the smaller of the two directions); to resolve, the geometric-mean
    standard error of the effect's parameters (spec units); ``planned_sd``: the Δχ²'s standard
    deviation (separation only); ``match``: random poses whose mean criterion reaches the
    plan's (None: more than :data:`MATCH_LIMIT` × N); ``before``: the criterion on the
    session's poses alone."""

    meas: Measurements
    kind: str  #: "separate" or "resolve"
    hypotheses: tuple[str, ...]
    before: float
    planned: float
    random: float
    match: int | None
    planned_sd: float = float("nan")
    #: Separation: the fewest of the planned poses, in their order, after which the expected
    #: separation decides (:func:`~hexcal.diagnosis.selection.separates`; None: not all of them)
    decide: int | None = None
    notes: list[str] = field(default_factory=list)
    #: Separation, per hypothesis taken as true: (the mean Δχ² the other leaves beyond it,
    #: both refitted on every pose — the parameter counts' difference included — and its
    #: standard deviation) after the planned poses
    expected: dict[str, tuple[float, float]] = field(default_factory=dict)
    #: s from the session's last pose to the first planned one, less one pose's pace
    wait: float = 0.0
    #: Separation: per hypothesis taken as true, the Δχ²'s standard deviation from the new
    #: poses' noise alone (the session's poses held as recorded)
    noise_sd: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class When:
    """When the planned poses are recorded, and at what temperature: ``wait_s`` before the
    first (None: the plan chooses, :func:`waits_to_try` up to ``max_wait_s``), at
    ``temperature`` °C held (None: the session's last; a lab with a climate-controlled room or
    chamber may state another)."""

    wait_s: float | None = None
    max_wait_s: float | None = None
    temperature: float | None = None
    #: (low, high) °C the lab can hold the rig at (a climate-controlled room or chamber): the
    #: plan may then choose the temperature too (:func:`temperatures_to_try`)
    temperatures: tuple[float, float] | None = None


@dataclass
class _Setting:
    """What the criterion needs: the fits, the robot they give, the noise level."""

    problem: Problem
    base: ModelFit
    fits: dict[str, ModelFit]
    robot: Robot
    s2: float
    dt: float  #: s between poses
    hypotheses: tuple[str, ...]
    #: °C the new poses are taken at: the session's last, or the temperature the lab will hold
    hold: float | None = None


def plan_poses(
    problem: Problem,
    effects: tuple[str, ...],
    n_poses: int,
    separate: tuple[str, str] | None = None,
    resolve: str | None = None,
    rng: np.random.Generator | None = None,
    n_candidates: int = N_CANDIDATES,
    when: When | None = None,
) -> Plan:
    """Plan ``n_poses`` poses for ``problem``'s session with ``effects`` in the model (see the
    module docstring): ``separate`` two hypotheses (effect names, or :data:`GEOMETRY`), or
    ``resolve`` one effect; ``when``: the wait before them and the temperature they are taken
    at (:class:`When`; None: the wait the plan chooses, the session's last temperature). Raises
    ValueError for an effect these data cannot carry or a hypothesis already in the model."""
    if (separate is None) == (resolve is None):
        raise ValueError("plan: give two hypotheses to separate, or one effect to resolve")
    if n_poses < 1:
        raise ValueError(f"plan: --poses must be at least 1 (got {n_poses})")
    rng = np.random.default_rng(0) if rng is None else rng
    hyps = tuple(separate) if separate is not None else (str(resolve),)
    when = When() if when is None else when
    setting = _setting(problem, effects, hyps, when.temperature)
    pool = _candidates(problem, setting.robot, n_candidates, rng)
    if len(pool[0]) < n_poses:
        raise ValueError(
            f"plan: only {len(pool[0])} of {n_candidates} random poses are reachable within the "
            "session's range: check leg_range_mm and joint_limit_deg in robot.json"
        )
    crit = _Criterion(setting, resolve is not None)
    both = _with_edges(problem, setting.robot, pool, rng)
    crit, wait, chosen = _schedule(crit, both, n_poses, when)
    setting = crit.s
    P, R = both[0][chosen], both[1][chosen]
    t_new = np.round(_times(problem, setting.dt, n_poses, wait), 3)
    planned, sd = crit.final(P, R, t_new)
    draws = [_draw(pool, n_poses, rng) for _ in range(N_RANDOM)]
    random = float(np.mean([crit.final(d[0], d[1], t_new)[0] for d in draws]))
    match = _match(crit, problem, planned, t_new, rng, n_candidates)
    meas = _table(problem, setting, P, R, t_new)
    expected, decide, noise_sd = {}, None, {}
    if resolve is None:
        lam, sd_of = crit.directions(P, R, t_new)
        expected = {h: (lam[h], sd_of[h]) for h in lam}
        noise_sd = crit.directions(P, R, t_new, noise_only=True)[1]
        decide = crit.decided_after(P, R, t_new)
    return Plan(
        meas,
        "resolve" if resolve is not None else "separate",
        hyps,
        crit.final(P[:0], R[:0], t_new[:0])[0],
        planned,
        random,
        match,
        sd,
        decide,
        _notes(problem, setting, wait, when),
        expected,
        wait,
        noise_sd,
    )


def _notes(problem: Problem, s: _Setting, wait: float, when: When) -> list[str]:
    """What the plan takes for granted: free poses, when they are recorded, at what
    temperature (and whether the session's own temperature still moved at its end)."""
    notes = [
        "free poses only: a plan under a clamp is not made (record these with no leg clamped)",
        (
            f"record the first pose {wait:.0f} s after the session's last "
            f"({'the wait the plan chose' if when.wait_s is None else 'the wait asked for'}), "
            "then"
            if wait > 0
            else "record them as the session goes on,"
        )
        + f" one every {s.dt:.0f} s (the session's pace): the t column",
    ]
    temp = problem.meas.temperature
    if temp is None or s.hold is None:
        return notes
    stated = when.temperature is not None or s.hold != float(temp[-1])
    notes.append(
        f"at {s.hold:.2f} °C held through the poses ("
        + (
            "the temperature asked for"
            if when.temperature is not None
            else "the plan's choice: reached during the wait"
            if stated
            else "the session's last" + (", held through the wait" if wait > 0 else "")
        )
        + "): the temperature column — the diagnosis takes each pose at the temperature it "
        "records, so a temperature that moves on with time makes the wait worth less"
    )
    rate = end_trend(problem.meas)
    if not stated and abs(rate) * max(wait, s.dt) / 3600.0 > 0.1:
        notes.append(
            f"the session's temperature was still moving at its end ({rate:+.2f} K/h): hold "
            f"the room or the chamber at {s.hold:.2f} °C, or plan again once it has settled"
        )
    return notes


def end_trend(meas: Measurements) -> float:
    """K/h: the temperature's slope over the last quarter of the session's poses (least
    squares), 0 without a temperature column."""
    if meas.temperature is None or len(meas) < 4:
        return 0.0
    k = max(len(meas) // 4, 3)
    t, temp = np.asarray(meas.t[-k:], float), np.asarray(meas.temperature[-k:], float)
    if np.ptp(t) <= 0:
        return 0.0
    return float(np.polyfit(t, temp, 1)[0] * 3600.0)


#: Candidate poses each (wait, temperature) of a schedule is tried with before the chosen one
#: is planned with them all.
SCHEDULE_CANDIDATES = 500


def _schedule(crit: _Criterion, pool, n: int, when: When) -> tuple[_Criterion, float, np.ndarray]:
    """(the criterion at the temperature chosen, the wait s before the first pose, the indices
    of ``n`` poses of ``pool``). The wait and temperature asked for; else, where the
    hypotheses' separation depends on when the poses are recorded (an effect of the time, a
    drift's) or at what temperature (where the lab can hold one of ``when.temperatures``),
    each wait of :func:`waits_to_try` at each temperature the rig reaches by then
    (:func:`temperatures_to_try`) is tried on :data:`SCHEDULE_CANDIDATES` of the poses, and the
    one after which the least lab time (the wait and the poses' own, at the session's pace)
    decides is planned — the one that separates most when none does."""
    s = crit.s
    waits = [0.0] if when.wait_s is None else [float(when.wait_s)]
    warm = when.temperatures is not None and crit.warmed(pool, max(when.temperatures))
    if when.wait_s is None and not crit.resolve:
        tried = waits_to_try(s.problem, when.max_wait_s)
        if crit.timed(pool, tried[-1]) or warm:
            waits = tried
    options = [(w, h) for w in waits for h in temperatures_to_try(s, w, when if warm else When())]
    if len(options) == 1:
        w = options[0][0]
        t = _times(s.problem, s.dt, n, w)
        return crit, w, crit.greedy(pool, n, t[(n - 1) // 2 :][:1])
    few = (pool[0][:SCHEDULE_CANDIDATES], pool[1][:SCHEDULE_CANDIDATES])
    best: tuple[float, float, float, float | None] | None = None
    crits = {s.hold: crit}
    for w, hold in options:
        if hold not in crits:
            crits[hold] = _Criterion(replace(s, hold=hold), crit.resolve)
        c = crits[hold]
        t = _times(s.problem, s.dt, n, w)
        chosen = c.greedy(few, n, t[(n - 1) // 2 :][:1])
        P, R = few[0][chosen], few[1][chosen]
        k = c.decided_after(P, R, t)
        cost = np.inf if k is None else w + k * s.dt
        value = c.final(P, R, t)[0]
        if best is None or (cost, -value) < (best[0], -best[1]):
            best = (cost, value, w, hold)
    assert best is not None
    _, _, w, hold = best
    t = _times(s.problem, s.dt, n, w)
    return crits[hold], w, crits[hold].greedy(pool, n, t[(n - 1) // 2 :][:1])


def temperatures_to_try(s: _Setting, wait: float, when: When) -> list[float | None]:
    """The temperatures (°C) a schedule tries after ``wait`` s: the one held (the session's
    last, or the one asked for), and where the lab can hold any within ``when.temperatures``,
    the farthest it reaches each way by then, the rig's temperature changing no faster than
    the session saw it change (its range over its time span)."""
    out: list[float | None] = [s.hold]
    temp = s.problem.meas.temperature
    if when.temperatures is None or temp is None or s.hold is None or when.temperature is not None:
        return out
    lo, hi = sorted(when.temperatures)
    span = float(np.ptp(np.asarray(s.problem.meas.t, float)))
    rate = float(np.ptp(temp)) / span if span > 0 else 0.0
    reach = rate * (wait + s.dt)
    for far in (max(lo, s.hold - reach), min(hi, s.hold + reach)):
        if abs(far - s.hold) >= 0.1 and all(abs(far - o) >= 0.1 for o in out if o is not None):
            out.append(round(far, 2))
    return out


def waits_to_try(problem: Problem, max_wait_s: float | None = None) -> list[float]:
    """The waits (s) a plan tries, shortest first: none, then 1/8, 1/4, 1/2 and all of the
    longest (``max_wait_s``; None: as long as the session took, a time baseline twice the
    session's)."""
    t = np.asarray(problem.meas.t, float)
    longest = float(np.ptp(t)) if max_wait_s is None else float(max_wait_s)
    if longest <= 0:
        return [0.0]
    return [0.0, *(longest / 2.0**k for k in (3, 2, 1, 0))]


def _setting(
    problem: Problem,
    effects: tuple[str, ...],
    hyps: tuple[str, ...],
    temperature: float | None = None,
) -> _Setting:
    """Fit the model and each hypothesis to the session's poses; the new poses at
    ``temperature`` (None: the session's last)."""
    for h in hyps:
        if h == GEOMETRY:
            continue
        get_effect(h)  # an unknown name is refused with the catalogue listed
        if h in effects:
            raise ValueError(f"plan: {h} is already in the model (--add): nothing to decide")
        why = problem.missing(h)
        if why:
            raise ValueError(f"plan: effect {h!r} cannot be fitted to these data: {why}")
    if len(set(hyps)) != len(hyps):
        raise ValueError("plan: the two hypotheses to separate are the same")
    base = fit_model(problem, effects, cross_validate=False)
    fits = {
        h: base if h == GEOMETRY else fit_model(problem, (*effects, h), False, seed_fit=base)
        for h in hyps
    }
    s2 = 1.0
    if problem.sigmas is None:  # the noise level of the best of the hypotheses
        s2 = min(f.chi2 / f.dof for f in fits.values())
    dt = float(np.median(np.diff(problem.meas.t))) if len(problem.meas) > 1 else 10.0
    robot = fitted_robot(problem.design, base.refinement)
    temp = problem.meas.temperature
    hold = None if temp is None else float(temp[-1] if temperature is None else temperature)
    return _Setting(problem, base, fits, robot, s2, max(dt, 1.0), hyps, hold)


def _times(problem: Problem, dt: float, n: int, wait: float = 0.0) -> np.ndarray:
    """(n,) s: the new poses' times, the first ``wait`` + ``dt`` after the session's last."""
    return float(problem.meas.t[-1]) + wait + dt * np.arange(1, n + 1)


def _draw(pool: tuple[np.ndarray, np.ndarray], n: int, rng: np.random.Generator):
    i = rng.choice(len(pool[0]), n, replace=False)
    return pool[0][i], pool[1][i]


def _match(crit, problem, planned, t_new, rng, n_candidates) -> int | None:
    """The fewest random reachable poses (doubling, then halving the gap) whose mean criterion
    (over :data:`N_RANDOM` // 4 draws) reaches ``planned``, recorded after the same wait as the
    plan's (``t_new``: its times); None beyond :data:`MATCH_LIMIT` × n."""
    n, dt = len(t_new), crit.s.dt
    wait = float(t_new[0]) - float(problem.meas.t[-1]) - dt

    def reaches(k: int) -> bool:
        vals = []
        for _ in range(max(N_RANDOM // 4, 1)):
            pool = _candidates(problem, crit.s.robot, max(k, 1), rng)
            t = _times(problem, dt, len(pool[0]), wait)
            vals.append(crit.final(pool[0], pool[1], t)[0])
        return crit.better(float(np.mean(vals)), planned)

    lo, hi = n, n
    while not reaches(hi):
        lo, hi = hi, 2 * hi
        if hi > MATCH_LIMIT * n:
            return None
    while hi - lo > max(1, lo // 10):
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if reaches(mid) else (mid, hi)
    return hi


def _table(problem: Problem, s: _Setting, P: np.ndarray, R: np.ndarray, t: np.ndarray):
    """The plan as a measurement table: the readings the fitted model predicts at each pose
    (refused, :class:`~hexcal.estimate.predict.PredictionError`, were one beyond a stroke or a
    joint's limit)."""
    temp = None if s.hold is None else np.full(len(P), s.hold)
    model = s.base.leg_model(problem.design)
    rho = model.readings(P, R, t, temp, check_limits=True)
    first = int(problem.meas.pose_id.max()) + 1
    return Measurements.from_arrays(
        P,
        Rotation.from_matrix(R),
        rho,
        step="plan",
        t=t,
        pose_id=np.arange(first, first + len(P)),
        temperature=temp,
    )


class _Criterion:
    """The plan's criterion on the session's poses plus new ones, from whitened rows."""

    def __init__(self, s: _Setting, resolve: bool) -> None:
        self.s, self.resolve = s, resolve
        m = len(s.problem.meas)
        d = s.problem.data
        w = leg_whiteners(s.robot.a, s.robot.b, d.position, d.rotation, _sigmas(s.problem))
        #: (6M,) the session's residuals at the model's fit, whitened as the rows are
        self.residual = (w @ s.base.residuals[..., None]).ravel() / np.sqrt(s.s2)
        self.old = [self._gram(x) for x in self._rows_at(np.zeros((0, 3)), np.zeros((0, 3, 3)))]
        self.m = m

    def better(self, value: float, target: float) -> bool:
        return value <= target if self.resolve else value >= target

    def timed(self, pool, wait: float) -> bool:
        """Whether the hypotheses' separation depends on when poses are recorded: the
        criterion of a few of ``pool``'s poses now and ``wait`` s later differs."""
        if wait <= 0:
            return False
        P, R = pool[0][: BATCH // 10], pool[1][: BATCH // 10]
        now, later = (
            self.final(P, R, _times(self.s.problem, self.s.dt, len(P), w))[0] for w in (0.0, wait)
        )
        return not np.isclose(now, later, rtol=1e-6, atol=1e-9)

    def warmed(self, pool, temperature: float) -> bool:
        """Whether the hypotheses' separation depends on the temperature the poses are
        recorded at: the criterion of a few of ``pool``'s poses at the held temperature and at
        ``temperature`` (1 K away if the same) differs."""
        if self.s.hold is None or self.resolve:
            return False
        other = temperature if abs(temperature - self.s.hold) >= 0.1 else self.s.hold + 1.0
        P, R = pool[0][: BATCH // 10], pool[1][: BATCH // 10]
        t = _times(self.s.problem, self.s.dt, len(P))
        there = _Criterion(replace(self.s, hold=other), False)
        return not np.isclose(self.final(P, R, t)[0], there.final(P, R, t)[0], 1e-6, 1e-9)

    def _rows_at(self, P: np.ndarray, R: np.ndarray, t: np.ndarray | None = None):
        """Per model: whitened rows (n, 6, p) of the session's poses followed by the new ones;
        the model's columns first, the quantity of interest last (the other hypothesis'
        fitted contribution, or the resolved effect's columns)."""
        s = self.s
        data = _data(s, P, R, np.zeros(0) if t is None else t)
        w = leg_whiteners(
            s.robot.a, s.robot.b, data.position, data.rotation, _sigmas(s.problem)
        ) / np.sqrt(s.s2)
        geo = _geometry_rows(s.base, data)
        base = [get_effect(e).basis(data) for e in s.base.effects if e != "offset"]
        out = []
        for h in s.hypotheses:
            own = [] if h == GEOMETRY else [get_effect(h).basis(data)]
            if self.resolve:
                cols = [geo, *base, *own]
            else:
                other = next(o for o in s.hypotheses if o != h)
                cols = [geo, *base, *own, _contribution(s, other, data)[..., None]]
            out.append(w @ np.concatenate(cols, axis=-1))
        return out

    @staticmethod
    def _gram(x: np.ndarray) -> np.ndarray:
        flat = x.reshape(-1, x.shape[-1])
        return flat.T @ flat

    def _q(self) -> int:
        h = self.s.hypotheses[0]
        return len(get_effect(h).params(self.s.problem.design)) if self.resolve else 1

    def _value(self, info: np.ndarray) -> np.ndarray:
        """Separation: each model's noncentrality (K, n_hyp) → the smaller that counts;
        resolve: the geometric-mean standard error (spec units)."""
        if self.resolve:
            sign, logdet = np.linalg.slogdet(info[..., 0, :, :])
            return np.where(sign > 0, np.exp(-logdet / (2 * info.shape[-1])), np.inf)
        lam = info[..., 0, 0]
        keep = [i for i, h in enumerate(self.s.hypotheses) if _other(self.s, h) != GEOMETRY]
        return lam[..., keep].min(axis=-1)

    def greedy(self, pool, n: int, t_mid: np.ndarray) -> np.ndarray:
        """Indices of ``n`` poses of ``pool`` picked one by one, each the best given those
        before it."""
        P, R = pool
        t = np.full(len(P), t_mid[0])
        rows = [x[self.m :] for x in self._rows_at(P, R, t)]
        grams = [g.copy() for g in self.old]
        q = self._q()
        free = np.ones(len(P), bool)
        chosen = []
        for _ in range(n):
            idx = np.where(free)[0]
            info = np.stack(
                [selection.schur_after(g, x[idx], q) for g, x in zip(grams, rows, strict=True)],
                axis=1,
            )
            vals = self._value(info)
            best = int(idx[np.argmin(vals) if self.resolve else np.argmax(vals)])
            chosen.append(best)
            free[best] = False
            for g, x in zip(grams, rows, strict=True):
                g += x[best].T @ x[best]
        return np.array(chosen)

    def final(self, P: np.ndarray, R: np.ndarray, t: np.ndarray) -> tuple[float, float]:
        """(criterion, Δχ²'s standard deviation) with the session's poses and these."""
        if self.resolve:
            rows = self._rows_at(P, R, t)
            info = selection.schur_block(self._gram(rows[0]), self._q())
            return float(self._value(info[None, None])[0]), float("nan")
        lam, sd = self.directions(P, R, t)
        worst = min(lam, key=lambda h: lam[h])
        return lam[worst], sd[worst]

    def decided(self, P: np.ndarray, R: np.ndarray, t: np.ndarray) -> bool:
        """Whether the session's poses and these decide, whichever hypothesis is true
        (:func:`~hexcal.diagnosis.selection.separates`)."""
        mean, sd = self.directions(P, R, t)
        ref = self.s.base.refinement
        rows = ref.dof + len(ref.x) + 6 * len(P)

        def count(h: str) -> int:
            return 0 if h == GEOMETRY else len(get_effect(h).params(self.s.problem.design))

        return all(
            selection.separates(
                mean[h],
                sd[h],
                count(h) - count(_other(self.s, h)),
                rows,
                _other(self.s, h) == GEOMETRY,
            )
            for h in mean
        ) and (GEOMETRY in self.s.hypotheses or self._vuong_apart(P, R, t))

    def _vuong_apart(self, P: np.ndarray, R: np.ndarray, t: np.ndarray) -> bool:
        """Whether Vuong's test would put the two apart whichever is true, two standard
        deviations short (:func:`~hexcal.diagnosis.selection.predicted_vuong_z` ≥
        :data:`~hexcal.diagnosis.selection.HELDOUT_Z`): the look-alike rule asks it of
        non-nested hypotheses besides their Δχ²."""
        rows = self._rows_at(P, R, t)
        flat = [r[..., :-1].reshape(-1, r.shape[-1] - 1) for r in rows]
        return all(
            selection.predicted_vuong_z(flat[1 - i], flat[i], self.residual) >= selection.HELDOUT_Z
            for i in range(len(flat))
        )

    def decided_after(self, P: np.ndarray, R: np.ndarray, t: np.ndarray) -> int | None:
        """The fewest of these poses, in their order, after which the question is decided
        (:meth:`decided`); None: not after all of them."""
        return next((n for n in range(len(P) + 1) if self.decided(P[:n], R[:n], t[:n])), None)

    def directions(
        self, P: np.ndarray, R: np.ndarray, t: np.ndarray, noise_only: bool = False
    ) -> tuple[dict[str, float], dict[str, float]]:
        """Per hypothesis taken as true: (the expected Δχ² the other leaves beyond it, both
        refitted on the session's poses and these, and that Δχ²'s standard deviation), keyed
        by the true one's name: the predictive distribution given the session's residuals
        (:func:`~hexcal.diagnosis.selection.predicted_delta_chi2`, linear at the model's fit):
        the session's part is recorded already; the new poses' residuals are what the true
        hypothesis fitted to the session predicts, with their noise and that fit's own spread
        (``noise_only``: their noise alone, what redrawing only the new poses' noise spreads
        the Δχ² by)."""
        rows = self._rows_at(P, R, t)
        flat = [r[..., :-1].reshape(-1, r.shape[-1] - 1) for r in rows]
        mean, sd = {}, {}
        for i, h in enumerate(self.s.hypotheses):
            true = _other(self.s, h)  # model i is the other's: true's columns are model 1 − i's
            if true == GEOMETRY:  # the geometry alone has no contribution to show
                continue
            mean[true], sd[true] = selection.predicted_delta_chi2(
                flat[1 - i], flat[i], self.residual, noise_only
            )
        return mean, sd


def _other(s: _Setting, h: str) -> str:
    return next(o for o in s.hypotheses if o != h) if len(s.hypotheses) > 1 else GEOMETRY


def _sigmas(problem: Problem):
    return problem.sigmas if problem.sigmas is not None else DEFAULT_SIGMAS


def _data(s: _Setting, P: np.ndarray, R: np.ndarray, t: np.ndarray) -> EffectData:
    """The effects' inputs over the session's poses followed by new ones (their readings as the
    fitted model predicts them, the session's last temperature and extra columns)."""
    d = s.problem.data
    n = len(P)
    rho = LegModel(s.robot).geometric(P, R) - s.robot.offsets
    temp = None if d.temperature is None else np.concatenate([d.temperature, _temp(s, n)])
    return EffectData(
        np.concatenate([d.readings, rho]),
        np.concatenate([d.position, P]),
        np.concatenate([d.rotation, R]),
        np.concatenate([np.asarray(d.t, float), t]),
        temp,
        d.robot,
        d.a,
        d.b,
        columns={k: np.concatenate([v, np.full(n, v[-1])]) for k, v in d.columns.items()},
    )


def _temp(s: _Setting, n: int) -> np.ndarray:
    return np.full(n, s.hold) if s.hold is not None else np.zeros(n)


def _geometry_rows(fit: ModelFit, data: EffectData) -> np.ndarray:
    """(n, 6, 6·c) the leg lengths' derivatives by the geometry at the fitted one."""
    ref = fit.refinement
    args = (data.position, data.rotation, data.readings, data.robot.offsets)
    return pose_jacobian(ref.x, ref.layout, *args)[1]


def _contribution(s: _Setting, name: str, data: EffectData) -> np.ndarray:
    """(n, 6) mm hypothesis ``name``'s fitted contribution to the leg lengths (0: the
    geometry alone)."""
    if name == GEOMETRY:
        return np.zeros((len(data), 6))
    return get_effect(name).basis(data) @ _values(s, name)


def _values(s: _Setting, name: str) -> np.ndarray:
    """(q,) hypothesis ``name``'s fitted parameter values, in their spec units."""
    ref = s.fits[name].refinement
    return np.array([ref.value(p.name) for p in get_effect(name).params(s.problem.design)])
