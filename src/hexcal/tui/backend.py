"""Where the text UI's devices come from: the real rig (a device configuration file), the mock
rig (simulated devices behind the real drivers, a robot hiding an effect), or an instant mock
(no drivers; for the UI's own tests)."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hexcal.acquire.acquisition import StillWindow
from hexcal.acquire.devices import DevicesConfig
from hexcal.model.robot import Robot
from hexcal.procedure.recording import BusStatus, LiveRecorder, Mover


@dataclass
class Rig:
    """An open rig: ``acquisition`` (``record()``, ``latest()``), the leg-encoder driver for its
    status (or None), a motion controller (mock only, else None), the device configuration to
    store in the session, and, on a simulated rig, the ``truth`` and the ``hidden`` effect."""

    acquisition: LiveRecorder
    encoders: BusStatus | None = None
    mover: Mover | None = None
    devices: DevicesConfig | None = None
    truth: Robot | None = None
    hidden: dict[str, Any] | None = None
    #: Reads the structure temperature (degC), when the rig has a thermometer; else the
    #: operator types it (key t in the recording screen).
    thermometer: Callable[[], float] | None = None


@dataclass
class Backend:
    """How to open the rig. ``design``: the robot as drawn (the calibration's starting point
    for everything but the geometry). ``label``: one line for the start screen."""

    design: Robot
    label: str
    simulated: bool = False
    #: The label in the screens' title bar, short enough for 80 columns (None: ``label``).
    title: str | None = None
    _stack: contextlib.ExitStack = field(default_factory=contextlib.ExitStack, repr=False)

    def open(self) -> Rig:
        """Open the devices (blocking: call it from a worker). Closed by :meth:`close`."""
        raise NotImplementedError

    def close(self) -> None:
        self._stack.close()


@dataclass
class RealBackend(Backend):
    """The lab's rig from a device configuration file (see ``hexcal devices check``)."""

    config_path: Path = field(kw_only=True)

    def __post_init__(self) -> None:
        if self.title is None:
            self.title = f"rig {self.config_path.name}"

    def open(self) -> Rig:
        from hexcal.acquire.devices import load_devices_config
        from hexcal.acquire.live import open_rig

        cfg = load_devices_config(self.config_path)
        live = self._stack.enter_context(open_rig(cfg))
        return Rig(live.acquisition, live.encoders, None, cfg)


@dataclass
class MockBackend(Backend):
    """The mock rig: a simulated robot built off ``design`` hiding one effect (drawn from
    ``seed`` unless ``effect`` is given), served through the real drivers; a mock motion
    controller does the clamping and moving the operator would."""

    seed: int = 1
    effect: str | None = None
    window_s: float = 0.25

    def open(self) -> Rig:
        from hexcal.acquire.live import open_rig
        from hexcal.app.demo import hidden_robot
        from hexcal.mock_hw.rig import mock_rig

        hr = hidden_robot(self.seed, self.effect)
        rig = self._stack.enter_context(mock_rig(hr.truth, seed=self.seed, effects=[hr.hook]))
        live = self._stack.enter_context(
            open_rig(rig.config, StillWindow(duration_s=self.window_s))
        )
        rig.reproducible(live.acquisition)  # the same seed, the same session
        robot = rig.robot
        return Rig(
            live.acquisition,
            live.encoders,
            rig.motion,
            rig.config,
            hr.truth,
            hr.hidden(),
            thermometer=lambda: robot.temperature(robot.clock()),
        )


@dataclass
class InstantBackend(Backend):
    """A simulated robot sampled instantly, without drivers or threads (the UI's tests)."""

    seed: int = 1
    effect: str | None = "gain"

    def open(self) -> Rig:
        from hexcal.app.demo import hidden_robot
        from hexcal.mock_hw.instant import InstantAcquisition
        from hexcal.mock_hw.motion import MockMotionController
        from hexcal.mock_hw.robot import MockRobot

        hr = hidden_robot(self.seed, self.effect)
        robot = MockRobot(hr.truth, effects=[hr.hook], seed=self.seed)
        acq = InstantAcquisition(robot)
        acq.refresh()
        return Rig(
            acq, None, MockMotionController(robot, seed=self.seed), None, hr.truth, hr.hidden()
        )


def mock_backend(seed: int = 1, effect: str | None = None, window_s: float = 0.25) -> MockBackend:
    from hexcal.sim.robots import left_hand

    return MockBackend(
        left_hand(),
        f"mock rig (simulated robot, seed {seed}, hidden effect"
        + (f": {effect})" if effect else " drawn at random)"),
        simulated=True,
        title=f"mock rig, seed {seed}" + (f", {effect}" if effect else ""),
        seed=seed,
        effect=effect,
        window_s=window_s,
    )


@contextlib.contextmanager
def opened(backend: Backend) -> Iterator[Rig]:
    """``with opened(backend) as rig``: open, and close whatever happens."""
    try:
        yield backend.open()
    finally:
        backend.close()
