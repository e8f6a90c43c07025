"""Look-alike sessions for the planner (:mod:`hexcal.diagnosis.plan`), shared by its test and
``benchmarks/plan_rates.py``: a session whose poses cannot tell two hypotheses apart, the truth
behind it, and the simulator that records more poses of the same robot afterwards.

The pairs (:data:`PAIRS`), one hidden per session:

- ``gain vs compliance`` on the motion base (:func:`hexcal.sim.robots.motion_base_design`):
  a common scale error of the legs (what a tracker scale error also gives), the issue's
  example. (Its legs' compliance hidden is no look-alike on these poses: whenever its evidence
  is very strong it is named alone, a common gain taking up about half of its Δχ² for six
  parameters' cost);
- ``thermal vs drift`` on the Left Hand, the temperature rising over the session: thermal
  expansion, or the tracker drifting, alternately;
- ``ujoint vs geometry`` on the Left Hand: the universal joints' axes offset at a size the
  geometry nearly absorbs (the "cannot be told apart" case), against nothing more.

Each session is short (:data:`FREE_POSES` free poses after the clamped sets) so that the poses
recorded leave the pair ambiguous. Effects are simulated on the whole recording, the planned
poses after the session's at the times and temperatures the plan's table gives (a drift's
time runs on through a planned wait; the temperature is what the plan asks the lab to hold,
the session's last unless stated).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hexcal.effects.drift import T_MID
from hexcal.io.measurements import Measurements
from hexcal.model.instruments import Instruments
from hexcal.model.robot import Robot
from hexcal.sim.inject import effect_hook, realistic_values
from hexcal.sim.robots import (
    MOTION_BASE_INSTRUMENTS,
    left_hand,
    motion_base_design,
    motion_base_plan,
    motion_base_values,
)
from hexcal.sim.session_sim import SessionPlan, perturbed_truth, simulate_session
from hexcal.sim.simulate import LengthEffect, PoseContext, Simulator
from hexcal.sim.verdict_cases import INSTRUMENTS

#: The look-alike pairs: (A, B) as ``hexcal plan --separate`` takes them.
PAIRS = {
    "gain vs compliance": ("gain", "compliance"),
    "thermal vs drift": ("thermal", "drift"),
    "ujoint vs geometry": ("geometry", "ujoint"),
}
#: Free poses after the clamped sets (8 per clamp and leg).
FREE_POSES = 10
#: The hidden effects' sizes, relative to their realistic ones, so that the session's poses
#: leave the pair ambiguous.
SCALE = {"gain": 0.03, "compliance": 0.15, "thermal": 0.3, "drift": 0.3, "ujoint": 0.25}
#: The range (× :data:`SCALE`) the benchmark draws a session's hidden size from, log-uniform,
#: until the session's poses leave the pair undecided. Gain and compliance are look-alikes on
#: these poses only in a narrow band: below it the hidden one alone has very strong evidence,
#: above it the poses decide (compliance takes up about half of a common gain's Δχ², gain's
#: six parameters cost it 5·ln n ≈ 34 more than compliance's one).
SIZES = {"gain vs compliance": (2.5, 5.5), "thermal vs drift": (0.5, 10.0)}
SIZES["ujoint vs geometry"] = (0.5, 10.0)


@dataclass
class LookAlike:
    """A session, what is hidden in it, and how to record more poses of the same robot."""

    meas: Measurements
    design: Robot
    instruments: Instruments
    pair: tuple[str, str]
    hidden: str  #: the hypothesis that is true (one of ``pair``)
    simulator: Simulator
    history: _History

    def record(
        self,
        P: np.ndarray,
        R: np.ndarray,
        t: np.ndarray,
        seed: int,
        temperature: np.ndarray | None = None,
    ) -> Measurements:
        """The session with free poses (P (N, 3) mm, R (N, 3, 3)) recorded after it at times
        t (N,) s — a plan's t column, its wait included — at ``temperature`` (N,) °C, a plan's
        temperature column (None: the session's last), each with the thermometer's 0.05 K
        jitter: the lab holds the temperature the plan asks for."""
        rng = np.random.default_rng([seed, 37])
        temp = self.meas.temperature
        last = 20.0 if temp is None else float(temp[-1])
        held = np.full(len(P), last) if temperature is None else np.asarray(temperature, float)
        tn = np.round(held + rng.normal(0.0, 0.05, len(P)), 2)
        Pm, Rm, rho = self.simulator.measure(rng, P, R, PoseContext(P, R, t, tn))
        m = self.meas
        first = int(m.pose_id.max()) + 1
        from scipy.spatial.transform import Rotation

        new = Measurements.from_arrays(
            Pm,
            Rotation.from_matrix(Rm),
            rho,
            step="plan",
            t=t,
            pose_id=np.arange(first, first + len(P)),
            temperature=None if temp is None else tn,
        )
        both = [m, new]
        return Measurements.from_arrays(
            np.concatenate([x.position for x in both]),
            np.concatenate([x.quaternion for x in both]),
            np.concatenate([x.readings for x in both]),
            leg=np.concatenate([x.leg for x in both]),
            constraint=np.concatenate([x.constraint for x in both]),
            step=np.concatenate([x.step for x in both]),
            t=np.concatenate([x.t for x in both]),
            pose_id=np.concatenate([x.pose_id for x in both]),
            temperature=None if temp is None else np.concatenate([temp, tn]),
        )


class _History:
    """A hidden effect evaluated over the whole recording: the session's poses (kept from the
    session's simulation) followed by the new ones, whose part is returned — on the session's
    own clock (a drift reckoned from the middle of the session's time span, as it was while
    the session was recorded: from the middle of the whole recording, the new poses' drift
    would step back by half of the time added, a wait's too)."""

    def __init__(self, name: str, values: np.ndarray, truth: Robot) -> None:
        self.name, self.values, self.truth = name, values, truth
        self.hook: LengthEffect = effect_hook(name, values, truth)
        self.past: PoseContext | None = None
        self.recording = True
        self.__name__ = getattr(self.hook, "__name__", "hidden")

    def __call__(self, readings: np.ndarray, ctx: PoseContext) -> np.ndarray:
        if self.recording or self.past is None:
            self.past = ctx
            return self.hook(readings, ctx)
        p = self.past
        t = np.asarray(p.t, float)
        later = effect_hook(self.name, self.values, self.truth, {T_MID: 0.5 * (t.min() + t.max())})
        n = len(p.t)
        whole = PoseContext(
            np.concatenate([p.position, ctx.position]),
            np.concatenate([p.rotation, ctx.rotation]),
            np.concatenate([p.t, ctx.t]),
            np.concatenate([p.temperature, ctx.temperature]),
        )
        # The session's rows only feed history (a drift's clock): their readings' exact
        # values do not matter to the new rows of these effects.
        old = np.repeat(readings[:1], n, axis=0)
        return later(np.concatenate([old, readings]), whole)[n:]


def case(pair: str, seed: int, scale: float = 1.0) -> LookAlike:
    """A look-alike session of ``pair`` (a key of :data:`PAIRS`), its geometry, noise and
    hidden effect drawn from ``seed``, the effect at ``scale`` × :data:`SCALE` of its realistic
    size."""
    a, b = PAIRS[pair]
    rng = np.random.default_rng([37, seed])
    if pair == "gain vs compliance":
        design = motion_base_design()
        base = motion_base_plan()
        plan = SessionPlan(**{**base.__dict__, "n_free": FREE_POSES})
        instruments = MOTION_BASE_INSTRUMENTS
    else:
        design = left_hand().model_copy(update={"platform_mass_kg": 20.0})
        plan = SessionPlan(temperature_rise_k=5.0, n_free=FREE_POSES)
        instruments = INSTRUMENTS
    hidden = b if b != "geometry" and (seed % 2 or a == "geometry") else a
    if pair == "gain vs compliance":
        hidden = "gain"
    truth = perturbed_truth(design, rng, plan)
    values = _values(hidden, rng, truth, scale)
    hook = _History(hidden, values, truth)
    meas, _ = simulate_session(design, seed, plan, effects=[hook], truth=truth)
    hook.recording = False
    sim = Simulator(truth, ranges=plan.ranges, noise=plan.noise, effects=[hook])
    return LookAlike(meas, design, instruments, (a, b), hidden, sim, hook)


def _values(name: str, rng: np.random.Generator, truth: Robot, scale: float) -> np.ndarray:
    size = scale * SCALE[name]
    if name == "compliance" and truth.name == "motion-base":
        return motion_base_values(name, rng, size)
    if name == "gain":  # one scale for every leg: what a tracker's scale error also gives
        return np.full(6, realistic_values(name, rng, truth, size)[0])
    return realistic_values(name, rng, truth, size)
