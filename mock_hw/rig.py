"""A whole simulated rig: one robot, its tracker, its six encoders and its motion controller.

:func:`mock_rig` starts everything and yields a :class:`MockRig` whose ``config`` reaches the
devices through the real transports (``ndimock://`` for the tracker, python-can's virtual bus
for the encoders), so whatever opens a real rig from a :class:`~hexcal.acquire.devices.DevicesConfig`
opens this one unchanged.
"""

from __future__ import annotations

import contextlib
import math
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from typing import Any

from hexcal.acquire.acquisition import Acquisition
from hexcal.acquire.devices import DevicesConfig, TrackerConfig
from hexcal.drivers.can_config import default_can_config
from hexcal.mock_hw.can_encoders import MockEncoderNodes
from hexcal.mock_hw.motion import MockMotionController
from hexcal.mock_hw.ndi_registry import register_robot, unregister
from hexcal.mock_hw.ndi_tracker import MockNDITracker
from hexcal.mock_hw.robot import DEFAULT_NOISE, MockRobot
from hexcal.model.robot import Robot
from hexcal.sim.simulate import LengthEffect, NoiseModel, PoseRanges

#: Python's thread switch interval (s) while a mock rig runs (see :func:`mock_rig`).
MOCK_SWITCH_INTERVAL_S = 0.0005

#: The host's frame-time uncertainty (s) below which a reproducible rig starts (see
#: :meth:`MockRig.reproducible`): a tenth of a frame at 60 Hz.
SETTLED_UNCERTAINTY_S = 0.0015
#: A reproducible rig's moves: how far (s) from any tracker frame, beyond the host's stamping
#: error, and how soon (s) after a SYNC (see :func:`quiet_instant_waiter`).
FRAME_CLEARANCE_S = 0.003
SYNC_FRESH_S = 0.003
#: ... and not sooner (s) after it than the host's stamp of it may differ from its instant.
SYNC_STALE_S = 0.0005

_names_lock = threading.Lock()
_names: set[str] = set()


@dataclass
class MockRig:
    """The running simulated rig: ``robot`` (the truth), ``tracker`` (mock NDI device),
    ``nodes`` (mock encoders), ``motion`` (mock motion controller), ``config`` (how to reach
    the devices)."""

    robot: MockRobot
    tracker: MockNDITracker
    nodes: MockEncoderNodes
    motion: MockMotionController
    config: DevicesConfig
    name: str

    def reproducible(self, acquisition: Acquisition) -> None:
        """Make what a session on this rig records depend on the seed and the moves alone, not
        on the host's timing or on when the operator pressed a key.

        The robot draws each measurement's noise from a stream of its own
        (:class:`~hexcal.mock_hw.robot.MockRobot`): the n-th measurement of a pose is the same
        whenever it is taken. Here ``acquisition``'s windows become so many samples (as many as
        its ``duration_s`` holds at the tracker's frame rate and the SYNC period) rather than
        so many seconds — a host too busy to read a frame or send a SYNC in time takes the
        next one, which the robot measures as the next measurement, so the window holds the
        same numbers —, and they start where the platform came to rest (the motion controller
        tells it: :meth:`~hexcal.acquire.acquisition.Acquisition.anchor`). The controller moves
        at the instant farthest from any tracker frame and SYNC (see
        :func:`quiet_instant_waiter`): the host stamps a sample within a fraction of a
        millisecond of the device's instant (measured: ≤ 0.5 ms for the frames, 50 µs for the
        SYNCs), so both sides agree on which measurement is a window's first. Then the
        platform is moved home, so the first pose too counts from a known instant."""
        period = self.config.can.sync_period_s
        if period > 0:
            d = acquisition.window.duration_s
            acquisition.window = replace(
                acquisition.window,
                tracker_samples=max(1, round(d * self.tracker.frame_rate_hz)),
                leg_samples=max(1, round(d / period)),
            )
        self.motion.before_move = quiet_instant_waiter(self, acquisition)
        self.motion.on_move = acquisition.anchor
        # The host's estimate of the tracker's frame times is loose for its first half second
        # (± 4 ms measured): wait until it is tight, and the SYNC grid's phase known.
        give_up = time.monotonic() + 3.0
        while time.monotonic() < give_up:
            trk = acquisition.latest()[0]
            settled = trk is not None and trk.t_uncertainty_s < SETTLED_UNCERTAINTY_S
            if settled and len(self.nodes.sync_times) == self.nodes.sync_times.maxlen:
                break
            time.sleep(0.02)
        self.motion.home()


def quiet_instant_waiter(rig: MockRig, acquisition: Acquisition) -> Callable[[], None]:
    """A function that returns at an instant at which a move leaves no doubt about which
    measurements come after it (see :meth:`MockRig.reproducible`).

    The robot puts a measurement after a move when the device's instant is; the host, when its
    stamp is (less its uncertainty, for a tracker frame). The two differ a little — a frame's
    stamp by its estimation error less its uncertainty (≤ 0.5 ms measured, more when a reply is
    late), a reading set's by the latency the host's bus clock includes (≈ 0.15 ms) — and a
    measurement whose instant falls in that gap would be counted after the move by one side
    only. The tracker's frames come on the device's own grid, so the instant is taken at least
    :data:`FRAME_CLEARANCE_S` beyond that gap from any frame. SYNCs come on the host's grid,
    late by milliseconds on a busy host, but never sooner than an answer deadline (half a period
    by default) after the last one was sent: so the instant is taken just after a SYNC, between
    :data:`SYNC_STALE_S` and :data:`SYNC_FRESH_S` after it. Within a second it returns
    anyway."""
    tracker, nodes = rig.tracker, rig.nodes
    frame = 1.0 / tracker.frame_rate_hz
    # The host sends its next SYNC a whole answer deadline after this one's send returned.
    fresh_s = min(SYNC_FRESH_S, 0.6 * rig.config.can.tpdo_deadline_s)

    def frame_gap() -> float:
        """How much later (s) the host counts a frame than its instant."""
        trk = acquisition.latest()[0]
        if trk is None:
            return 0.0
        n = round((trk.t - tracker.frame_time(1)) * tracker.frame_rate_hz) + 1
        return trk.t - tracker.frame_time(n) - trk.t_uncertainty_s

    def frames_clear(t: float, gap: float) -> bool:
        # A frame at instant m is after the move for the robot iff m >= t, for the host iff
        # m + gap >= t: in doubt between t − gap and t; kept FRAME_CLEARANCE_S from there.
        lo, hi = sorted((t, t - gap))
        n = math.floor((lo - tracker.frame_time(1)) / frame) + 1
        before, after = tracker.frame_time(n), tracker.frame_time(n + 1)
        return after > hi + FRAME_CLEARANCE_S and before < lo - FRAME_CLEARANCE_S

    def wait() -> None:
        gap = frame_gap()
        seen = nodes.sync_times[-1] if nodes.sync_times else None
        give_up = time.monotonic() + 1.0
        while time.monotonic() < give_up:
            last = nodes.sync_times[-1] if nodes.sync_times else None
            now = time.monotonic()
            fresh = last is not None and last != seen and SYNC_STALE_S < now - last < fresh_s
            if (fresh or last is None) and frames_clear(now, gap):
                return
            if last != seen:
                seen = last
            time.sleep(0.0002)

    return wait


def _rig_name(seed: int) -> str:
    """The rig's name from its seed (a session file records its devices' addresses, which
    name it), made unique among the rigs running in this process."""
    base = f"mock-seed{seed}"
    with _names_lock:
        name, n = base, 1
        while name in _names:
            n += 1
            name = f"{base}-{n}"
        _names.add(name)
    return name


@contextlib.contextmanager
def mock_rig(
    truth: Robot | None = None,
    *,
    seed: int = 0,
    noise: NoiseModel = DEFAULT_NOISE,
    effects: Sequence[LengthEffect] = (),
    ranges: PoseRanges | None = None,
    tracker_kwargs: dict[str, Any] | None = None,
    encoder_kwargs: dict[str, Any] | None = None,
) -> Iterator[MockRig]:
    """Start a simulated rig (default truth: the left-hand design) and stop it on exit."""
    if truth is None:
        from hexcal.sim.robots import left_hand

        truth = left_hand()
    name = _rig_name(seed)
    # The simulated devices are Python threads in this process: a real encoder answers a SYNC
    # within microseconds, the mock's thread only once it holds the GIL. Behind a busy thread
    # (the text UI rendering) the default 5 ms switch interval let its answers reach the bus
    # after the next SYNC — out of bus-time order, which no real bus does. Switching every
    # 0.5 ms keeps the mock's timing that of hardware; the interval is restored on exit.
    switch = sys.getswitchinterval()
    sys.setswitchinterval(min(switch, MOCK_SWITCH_INTERVAL_S))
    robot = MockRobot(truth, noise=noise, effects=effects, seed=seed)
    tracker = register_robot(name, robot, seed=seed, **(tracker_kwargs or {}))
    can_cfg = default_can_config(channel=f"hexcal-{name}")
    nodes = MockEncoderNodes(robot, can_cfg, seed=seed, **(encoder_kwargs or {})).start()
    try:
        yield MockRig(
            robot,
            tracker,
            nodes,
            MockMotionController(robot, ranges, seed=seed),
            DevicesConfig(
                tracker=TrackerConfig(url=f"ndimock://{name}", reset="command"), can=can_cfg
            ),
            name,
        )
    finally:
        nodes.stop()
        unregister(name)
        sys.setswitchinterval(switch)
        with _names_lock:
            _names.discard(name)
