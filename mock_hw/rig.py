"""A whole simulated rig: one robot, its tracker, its six encoders and its motion controller.

:func:`mock_rig` starts everything and yields a :class:`MockRig` whose ``config`` reaches the
devices through the real transports (``ndimock://`` for the tracker, python-can's virtual bus
for the encoders), so whatever opens a real rig from a :class:`~hexcal.acquire.devices.DevicesConfig`
opens this one unchanged.
"""

from __future__ import annotations

import contextlib
import sys
import uuid
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from hexcal.acquire.devices import DevicesConfig, TrackerConfig
from hexcal.drivers.can_config import default_can_config
from hexcal.mock_hw.can_encoders import MockEncoderNodes
from hexcal.mock_hw.motion import MockMotionController
from hexcal.mock_hw.ndi_tracker import MockNDITracker, register_robot, unregister
from hexcal.mock_hw.robot import DEFAULT_NOISE, MockRobot
from hexcal.model.robot import Robot
from hexcal.sim.simulate import LengthEffect, NoiseModel, PoseRanges

#: Python's thread switch interval (s) while a mock rig runs (see :func:`mock_rig`).
MOCK_SWITCH_INTERVAL_S = 0.0005


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
    name = f"rig{uuid.uuid4().hex[:8]}"
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
