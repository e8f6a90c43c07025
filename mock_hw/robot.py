"""The one simulated robot behind every mock device.

The mock tracker and the mock encoders both read this object, so what the tracker reports and
what the encoders report agree, as on a real rig: the true pose is set by the mock motion
controller; each device samples it with its own noise. Thread-safe: devices run in their own
threads.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import ClassVar

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.model.robot import Robot
from hexcal.sim.simulate import LengthEffect, NoiseModel, PoseContext, Simulator

#: A good optical tracker and encoder (1 sigma): 0.01 mm, 0.002 deg, 0.002 mm.
DEFAULT_NOISE = NoiseModel(0.01, 0.002, 0.002)


class MockRobot:
    """A simulated Gough platform with a true geometry, hidden effects and instrument noise.

    ``truth`` is the true robot (its offsets are the true offsets). Poses are (P (3,) mm,
    R (3, 3)) in the tracker frame. ``temperature`` (degC) is a callable of the monotonic time.

    Time: every move is stamped with ``clock()`` (s, monotonic by default), so an instrument can
    ask for the pose that was in effect at a past instant (:meth:`tracker_sample` with ``at``):
    a tracker measures its frame at a fixed instant and answers later. For tests and benchmarks,
    :attr:`encoder_latches` records when each set of encoder readings was taken.

    Noise: each measurement's noise is drawn from its own stream, seeded by (``seed``, the
    instrument, the pose it measures — the n-th pose moved to —, how many measurements of that
    pose the instrument took before it), not from one generator in the order the devices' threads
    happen to ask. So the same seed and the same moves give the same numbers, however the host's
    threads were scheduled and however long the operator waited between two keys.
    """

    #: How many (time, readings) entries :attr:`encoder_latches` keeps by default (10 s at 100 Hz
    #: SYNC; bounded so a long run's memory stays flat — benchmarks that need more pass
    #: ``log_len``).
    ENCODER_LOG_LEN = 1_000
    #: How many poses the motion history keeps. History-dependent effects (backlash) only need
    #: each leg's last motion, so a long tail is enough; bounded so a soak's memory stays flat.
    POSE_LOG_LEN = 200
    #: The noise streams: one per instrument, and one for measurements taken "now" rather than
    #: at a device's own instant (set-up reads, the instant acquisition of the UI's tests).
    _STREAMS: ClassVar[dict[str, int]] = {
        "tracker": 0x54524B,
        "encoders": 0x454E43,
        "tracker now": 0x544E57,
        "encoders now": 0x454E57,
    }

    def __init__(
        self,
        truth: Robot,
        noise: NoiseModel = DEFAULT_NOISE,
        effects: Sequence[LengthEffect] = (),
        seed: int = 0,
        clock: Callable[[], float] = time.monotonic,
        temperature: Callable[[float], float] = lambda t: 20.0,
        log_len: int | None = None,
    ):
        self.sim = Simulator(truth, noise=noise, effects=effects)
        self.truth = truth
        self.clock = clock
        self.temperature = temperature
        self.seed = seed
        self._lock = threading.Lock()
        #: How many poses the robot has been moved to (its first pose, at creation, is pose 0).
        self.moves = 0
        #: (instrument stream, pose) → measurements of that pose taken so far.
        self._taken: dict[tuple[str, int], int] = {}
        self._t0 = clock()
        self._P = np.asarray(truth.home.position, float)
        self._R = Rotation.from_quat(truth.home.quaternion, scalar_first=True).as_matrix()
        # (P, R, t, T, noise-free readings, pose number) of the last POSE_LOG_LEN poses moved
        # to, in order.
        self._poses: deque[tuple] = deque(maxlen=self.POSE_LOG_LEN)
        self.tool_visible = True
        #: (``clock()`` s, readings (6,) mm) of every :meth:`encoder_readings` call, oldest first:
        #: the instant each reading set was latched (the very array returned, so a device that
        #: keeps it can be matched by identity). Bounded: :attr:`ENCODER_LOG_LEN` entries.
        self.encoder_latches: deque[tuple[float, np.ndarray]] = deque(
            maxlen=log_len or self.ENCODER_LOG_LEN
        )
        self._readings = self._true_readings()

    # -- motion ---------------------------------------------------------------------------------
    def move_to(self, position: np.ndarray, rotation: np.ndarray) -> float:
        """Set the true pose (the mock motion controller's job); returns the ``clock()`` time
        (s) from which it is in effect."""
        with self._lock:
            self._P = np.asarray(position, float).copy()
            self._R = np.asarray(rotation, float).copy()
            self.moves += 1
            self._readings = self._true_readings()
            # Drop the measurement counts of poses that left the log: memory stays flat.
            oldest = self._poses[0][5]
            for key in [key for key in self._taken if key[1] < oldest]:
                del self._taken[key]
            return self._t0 + self._poses[-1][2]

    def true_pose(self) -> tuple[np.ndarray, np.ndarray]:
        with self._lock:
            return self._P.copy(), self._R.copy()

    def pose_at(self, at: float) -> tuple[np.ndarray, np.ndarray]:
        """The true pose (P (3,) mm, R (3, 3)) that was in effect at ``clock()`` time ``at`` (s):
        the last pose moved to at or before ``at``; the current pose for a future ``at``, the
        first pose for an ``at`` before the robot existed."""
        with self._lock:
            P, R = self._pose_at_locked(at)[:2]
            return P.copy(), R.copy()

    def _pose_at_locked(self, at: float) -> tuple:
        """The pose log entry (P, R, t, T, readings, pose number) in effect at ``clock()`` time
        ``at``."""
        rel = at - self._t0
        # Searched from the newest: instruments ask about the last few tens of ms.
        for entry in reversed(self._poses):
            if entry[2] <= rel:
                return entry
        return self._poses[0]

    def _true_readings(self) -> np.ndarray:
        """Noise-free readings (6,) mm at the current pose, effects included. Every pose the
        robot has been moved to is kept, so history-dependent effects (backlash) see the real
        order of motions."""
        t = self.clock() - self._t0
        P0, R0, T = self._P.copy(), self._R.copy(), self.temperature(t)
        if not self.sim.effects:
            rho = self.sim.readings(P0[None], R0[None])[0]
        else:
            hist = [*self._poses, (P0, R0, t, T)]
            P = np.array([p[0] for p in hist])
            R = np.array([p[1] for p in hist])
            ctx = PoseContext(P, R, np.array([p[2] for p in hist]), np.array([p[3] for p in hist]))
            rho = self.sim.readings(P, R, ctx)[-1]
        self._poses.append((P0, R0, t, T, rho, self.moves))
        return rho

    def _noise_rng(self, stream: str, pose: int) -> np.random.Generator:
        """The generator of the next measurement of pose number ``pose`` by ``stream`` (see the
        class docstring). Called with the lock held."""
        n = self._taken.get((stream, pose), 0)
        self._taken[stream, pose] = n + 1
        return np.random.default_rng([self.seed, self._STREAMS[stream], pose, n])

    # -- what the instruments see ----------------------------------------------------------------
    def tracker_sample(
        self, at: float | None = None
    ) -> tuple[np.ndarray, np.ndarray, float] | None:
        """A tracker measurement: position (3,) mm, unit quaternion (4,) scalar first, RMS error
        mm; None when the tool is out of view.

        ``at`` (s, on :attr:`clock`): measure the pose that was in effect at that instant (see
        :meth:`pose_at`) rather than the current one — a tracker's frame is exposed at its frame
        boundary, before the host's command reaches it. Visibility is the current one."""
        with self._lock:
            if not self.tool_visible:
                return None
            entry = self._poses[-1] if at is None else self._pose_at_locked(at)
            P0, R0 = (self._P, self._R) if at is None else entry[:2]
            rng = self._noise_rng("tracker now" if at is None else "tracker", entry[5])
            P, R, _ = self.sim.noise.apply(rng, P0[None], R0[None])
        q = Rotation.from_matrix(R[0]).as_quat(scalar_first=True)
        return P[0], q, float(self.sim.noise.sigma_position_mm)

    def encoder_readings(self, at: float | None = None) -> np.ndarray:
        """The six encoder readings (6,) mm with encoder noise, latched now or, with ``at`` (s,
        on :attr:`clock`), at that past instant — an encoder latches in hardware at the SYNC,
        however late its answer is computed. The latch time is logged in
        :attr:`encoder_latches`."""
        with self._lock:
            if at is None:
                t, rho, pose = self.clock(), self._readings.copy(), self._poses[-1][5]
            else:
                entry = self._pose_at_locked(at)
                t, rho, pose = at, entry[4].copy(), entry[5]
            sig = self.sim.noise
            if sig.reading_mm:
                rng = self._noise_rng("encoders now" if at is None else "encoders", pose)
                rho = rho + sig._draw(rng, sig.reading_mm, (6,))
            self.encoder_latches.append((t, rho))
        return rho
