"""The one simulated robot behind every mock device.

The mock tracker and the mock encoders both read this object, so what the tracker reports and
what the encoders report agree, as on a real rig: the true pose is set by the mock motion
controller; each device samples it with its own noise. Thread-safe: devices run in their own
threads.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.robot import Robot
from hexcal.simulate import LengthEffect, NoiseModel, PoseContext, Simulator

#: A good optical tracker and encoder (1 sigma): 0.01 mm, 0.002 deg, 0.002 mm.
DEFAULT_NOISE = NoiseModel(0.01, 0.002, 0.002)


class MockRobot:
    """A simulated Gough platform with a true geometry, hidden effects and instrument noise.

    ``truth`` is the true robot (its offsets are the true offsets). Poses are (P (3,) mm,
    R (3, 3)) in the tracker frame. ``temperature`` (degC) is a callable of the monotonic time.
    """

    def __init__(
        self,
        truth: Robot,
        noise: NoiseModel = DEFAULT_NOISE,
        effects: Sequence[LengthEffect] = (),
        seed: int = 0,
        clock: Callable[[], float] = time.monotonic,
        temperature: Callable[[float], float] = lambda t: 20.0,
    ):
        self.sim = Simulator(truth, noise=noise, effects=effects)
        self.truth = truth
        self.clock = clock
        self.temperature = temperature
        self._rng = np.random.default_rng(seed)
        self._lock = threading.Lock()
        self._t0 = clock()
        self._P = np.asarray(truth.home.position, float)
        self._R = Rotation.from_quat(truth.home.quaternion, scalar_first=True).as_matrix()
        self._poses: list[tuple] = []  # (P, R, t, T) of every pose moved to, in order
        self.tool_visible = True
        self._readings = self._true_readings()

    # -- motion ---------------------------------------------------------------------------------
    def move_to(self, position: np.ndarray, rotation: np.ndarray) -> None:
        """Set the true pose (the mock motion controller's job)."""
        with self._lock:
            self._P = np.asarray(position, float).copy()
            self._R = np.asarray(rotation, float).copy()
            self._readings = self._true_readings()

    def true_pose(self) -> tuple[np.ndarray, np.ndarray]:
        with self._lock:
            return self._P.copy(), self._R.copy()

    def _true_readings(self) -> np.ndarray:
        """Noise-free readings (6,) mm at the current pose, effects included. Every pose the
        robot has been moved to is kept, so history-dependent effects (backlash) see the real
        order of motions."""
        t = self.clock() - self._t0
        self._poses.append((self._P.copy(), self._R.copy(), t, self.temperature(t)))
        if not self.sim.effects:
            return self.sim.readings(self._P[None], self._R[None])[0]
        P = np.array([p[0] for p in self._poses])
        R = np.array([p[1] for p in self._poses])
        ctx = PoseContext(
            P, R, np.array([p[2] for p in self._poses]), np.array([p[3] for p in self._poses])
        )
        return self.sim.readings(P, R, ctx)[-1]

    # -- what the instruments see ----------------------------------------------------------------
    def tracker_sample(self) -> tuple[np.ndarray, np.ndarray, float] | None:
        """A tracker measurement: position (3,) mm, unit quaternion (4,) scalar first, RMS error
        mm; None when the tool is out of view."""
        with self._lock:
            if not self.tool_visible:
                return None
            P, R, _ = self.sim.noise.apply(self._rng, self._P[None], self._R[None])
        q = Rotation.from_matrix(R[0]).as_quat(scalar_first=True)
        return P[0], q, float(self.sim.noise.sigma_position_mm)

    def encoder_readings(self) -> np.ndarray:
        """The six encoder readings (6,) mm with encoder noise."""
        with self._lock:
            rho = self._readings.copy()
            sig = self.sim.noise
            if sig.reading_mm:
                rho = rho + sig._draw(self._rng, sig.reading_mm, (6,))
        return rho
