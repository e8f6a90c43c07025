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


@dataclass
class LookAlikeBackend(Backend):
    """The mock rig serving a look-alike session's robot (:mod:`hexcal.sim.plan_cases`): a
    session whose poses leave two hypotheses undecided (:meth:`write_session` writes it, its
    procedure done, to resume), and the same robot behind the real drivers to record more poses
    of — its hidden effect over the whole recording, the clock running on from the session's last
    pose, at its last temperature. A plan's wait and a temperature other than the last are not
    simulated here (the drivers stamp poses on the real clock): the simulator behind
    ``benchmarks/plan_rates.py`` (:meth:`hexcal.sim.plan_cases.LookAlike.record`) honours a
    plan's t and temperature columns."""

    look_alike: Any = field(kw_only=True, repr=False)  #: a plan_cases.LookAlike
    seed: int = 1
    window_s: float = 0.25

    def open(self) -> Rig:
        from hexcal.acquire.live import open_rig
        from hexcal.mock_hw.rig import mock_rig

        c = self.look_alike
        temps = c.meas.temperature
        last = None if temps is None else float(temps[-1])
        hook = _Later(c.history, float(c.meas.t.max()) + 1.0)
        sim = c.simulator
        rig = self._stack.enter_context(
            mock_rig(sim.robot, seed=self.seed, noise=sim.noise, effects=[hook], ranges=sim.ranges)
        )
        if last is not None:
            rig.robot.temperature = lambda t: last
        live = self._stack.enter_context(
            open_rig(rig.config, StillWindow(duration_s=self.window_s))
        )
        rig.reproducible(live.acquisition)
        return Rig(
            live.acquisition,
            live.encoders,
            rig.motion,
            rig.config,
            sim.robot,
            {"name": c.hidden},
            thermometer=None if last is None else (lambda: last),
        )

    def write_session(self, path: Path, procedure: str = "model42-direction-length") -> None:
        """The look-alike session as a session file at ``path``, every step of ``procedure``
        marked done (its poses are the look-alike's own), with the instruments' noise."""
        from hexcal.procedure.session import Session, SessionFile, StepProgress
        from hexcal.procedure.steps import load_procedure

        c = self.look_alike
        proc = load_procedure(procedure)
        session = Session.from_measurements(c.meas, c.design).model_copy(
            update={
                "instruments": c.instruments,
                "procedure": proc.model_dump(by_alias=True),
                "progress": [
                    StepProgress(step=s.name, status="done", poses=0, check="look-alike session")
                    for s in proc.expand()
                ],
            }
        )
        path.parent.mkdir(parents=True, exist_ok=True)
        SessionFile.create(path, session).close()


class _Later:
    """A hidden effect seen ``shift_s`` seconds later than the mock robot's clock says (its
    clock starts at 0; the session it continues ended before)."""

    def __init__(self, hook: Callable[..., Any], shift_s: float) -> None:
        self.hook, self.shift_s = hook, shift_s
        self.__name__ = getattr(hook, "__name__", "hidden")

    def __call__(self, readings: Any, ctx: Any) -> Any:
        from dataclasses import replace

        return self.hook(readings, replace(ctx, t=ctx.t + self.shift_s))


def look_alike_backend(
    pair: str, seed: int = 2, scale: float = 1.0, window_s: float = 0.25
) -> LookAlikeBackend:
    """The mock rig behind a look-alike session of ``pair`` (a key of
    :data:`hexcal.sim.plan_cases.PAIRS`), drawn from ``seed``."""
    from hexcal.sim.plan_cases import case

    c = case(pair, seed, scale)
    return LookAlikeBackend(
        c.design,
        f"mock rig behind a look-alike session ({pair}, seed {seed}; hidden: {c.hidden})",
        simulated=True,
        title=f"mock rig, {pair}, seed {seed}",
        look_alike=c,
        seed=seed,
        window_s=window_s,
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
