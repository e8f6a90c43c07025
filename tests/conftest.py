"""Shared fixtures: the paper's robot, a perturbed 'true' robot, simulators."""

from __future__ import annotations

import os

from hexcal.app.cli import single_thread_blas

# As the CLI does: one BLAS thread; these problems are too small to gain from more.
single_thread_blas()

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

# Fuzzing (tests marked ``fuzz``): a few hundred examples per reader and parser in the default
# run; HEXCAL_FUZZ=1 (CI's second pass) runs 10,000 each. No deadline: a loaded machine is
# not a failure.
settings.register_profile(
    "default",
    max_examples=200,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
settings.register_profile(
    "fuzz",
    max_examples=10_000,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
settings.load_profile("fuzz" if os.environ.get("HEXCAL_FUZZ") else "default")

from hexcal.sim.robots import left_hand
from hexcal.sim.simulate import Simulator

SHARED_EXAMPLE = Path(__file__).resolve().parents[1] / ".." / "shared" / "examples" / "left-hand"


@pytest.fixture(autouse=True)
def _sessions_in_tmp(tmp_path_factory, monkeypatch):
    """No test writes to, or lists, the user's own sessions directory."""
    monkeypatch.setenv("HEXCAL_SESSIONS", str(tmp_path_factory.mktemp("sessions")))


#: How long Textual's Pilot may wait, after each key, for this process to fall idle (s).
PILOT_IDLE_S = 0.05


@pytest.fixture
def quick_pilot(monkeypatch):
    """Textual's Pilot waits after each key until this process is idle (its CPU time no longer
    advancing with the clock), for up to 1 s, twice a key. With the mock rig's drivers reading
    the simulated devices on this process's threads it never falls idle, so every key cost 2 s.
    These tests wait for what they need explicitly (the screen's messages, which ``press``
    still awaits, the workers, the state they assert), so that heuristic wait is cut to
    :data:`PILOT_IDLE_S`; a process that does fall idle ends it sooner, as before."""
    import textual._wait
    import textual.app
    import textual.pilot

    wait = textual._wait.wait_for_idle

    async def quick(min_sleep: float = textual._wait.SLEEP_GRANULARITY, max_sleep: float = 1):
        await wait(min(min_sleep, PILOT_IDLE_S), min(max_sleep, PILOT_IDLE_S))

    monkeypatch.setattr(textual.app, "wait_for_idle", quick)
    monkeypatch.setattr(textual.pilot, "wait_for_idle", quick)


@pytest.fixture
def design():
    return left_hand()


@pytest.fixture
def truth(design):
    rng = np.random.default_rng(7)
    return design.with_geometry(
        design.a + rng.normal(0, 0.3, (6, 3)),
        design.b + rng.normal(0, 0.3, (6, 3)),
        design.offsets + rng.uniform(-1, 1, 6),
    )


@pytest.fixture
def clean_sim(truth):
    return Simulator(truth)


@pytest.fixture
def far_type_ii_clamp():
    """A search, ``(sim, robot) -> (leg 1-based, P (3,) mm, R (3, 3))``: a pose within
    ``sim``'s limits where that leg's Type II clamp (direction + length), set there, allows no
    pose (none in five searches of 200 rounds): where the mock operator, clamping at the
    workspace's edge, found itself stuck. Such poses are rare (about one in a thousand within
    ±90 mm and ±50° of home)."""
    from scipy.spatial.transform import Rotation

    from hexcal.model.workspace import NoFeasiblePose

    def allows_none(sim, k, point) -> bool:
        for seed in range(5):
            try:
                sim.type_ii(k, (1,), np.random.default_rng(seed), point=point)
                return False
            except NoFeasiblePose:
                pass
        return True

    def search(sim, robot):
        rng = np.random.default_rng(0)
        home = np.asarray(robot.home.position, float)
        for _ in range(50_000):
            P = home + rng.uniform(-90, 90, 3)
            R = Rotation.from_rotvec(rng.uniform(-0.9, 0.9, 3)).as_matrix()
            if not sim.feasible(P, R):
                continue
            for k in range(6):
                if allows_none(sim, k, P + R @ robot.b[k]):
                    return k + 1, P, R
        raise AssertionError("no pose within the limits where a Type II clamp allows none")

    return search


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


def instruments():
    """The instruments of the simulated sessions in the tests (1 sigma)."""
    from hexcal.model.instruments import EncoderNoise, Instruments, TrackerNoise

    return Instruments(
        tracker=TrackerNoise(position_sigma_mm=0.01, orientation_sigma_deg=0.002),
        encoders=EncoderNoise(reading_sigma_mm=0.002),
    )


@pytest.fixture(scope="session")
def backlash_diagnoses():
    """A session hiding backlash, diagnosed as Model 42 (verdict backlash) and Model 42 +
    backlash (verdict none): (before, after, measurements, design). Built once per test run."""
    from hexcal.diagnosis import diagnose
    from hexcal.sim.inject import effect_hook, realistic_values
    from hexcal.sim.session_sim import SessionPlan, perturbed_truth, simulate_session

    inst = instruments()
    design = left_hand().model_copy(update={"platform_mass_kg": 20.0})
    rng = np.random.default_rng(3)
    plan = SessionPlan(temperature_rise_k=5.0)
    truth = perturbed_truth(design, rng, plan)
    hook = effect_hook("backlash", realistic_values("backlash", rng, truth), truth)
    meas, _ = simulate_session(design, 3, plan, effects=[hook], truth=truth)
    before = diagnose(meas, design, 42, instruments=inst)
    after = diagnose(meas, design, 42, add=["backlash"], problem=before.problem, instruments=inst)
    return before, after, meas, design


def pytest_addoption(parser):
    """Point the device contract tests at real hardware (they run against the mocks anyway)."""
    parser.addoption(
        "--tracker-port", help="serial URL of a real NDI tracker (or HEXCAL_TRACKER_PORT)"
    )
    parser.addoption(
        "--can-interface", help="python-can interface of a real bus (or HEXCAL_CAN_INTERFACE)"
    )
    parser.addoption(
        "--can-channel", help="python-can channel of a real bus (or HEXCAL_CAN_CHANNEL)"
    )
    parser.addoption(
        "--can-mock-channel",
        help="channel the mock encoder nodes answer on, e.g. a second adapter wired to the first "
        "(or HEXCAL_CAN_MOCK_CHANNEL; default: the --can-channel)",
    )
    parser.addoption(
        "--tracker-baud", help="working baud rate for the real tracker (or HEXCAL_TRACKER_BAUD)"
    )


def pytest_configure(config):
    for opt, var in (
        ("--tracker-port", "HEXCAL_TRACKER_PORT"),
        ("--can-interface", "HEXCAL_CAN_INTERFACE"),
        ("--can-channel", "HEXCAL_CAN_CHANNEL"),
        ("--can-mock-channel", "HEXCAL_CAN_MOCK_CHANNEL"),
        ("--tracker-baud", "HEXCAL_TRACKER_BAUD"),
    ):
        value = config.getoption(opt)
        if value:
            os.environ[var] = value


@pytest.fixture
def registry_restored():
    """The effect registry (and the record of effect files run) as the test found it, after
    it: an in-process ``diagnose --explore`` loads the effect files it writes."""
    from hexcal.effects import CATALOGUE, plugins

    saved, files = dict(CATALOGUE), dict(plugins._files)
    yield
    CATALOGUE.clear()
    CATALOGUE.update(saved)
    plugins._files.clear()
    plugins._files.update(files)
