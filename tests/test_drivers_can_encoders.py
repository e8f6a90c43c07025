"""Contract tests: the CAN leg-encoder driver against six mock CANopen nodes.

Where the contract runs (the ``target``):

- ``virtual``: both sides on python-can's virtual bus in this process, a fresh channel per test;
- ``udp``: the six encoders in another process (:class:`~hexcal.mock_hw.can_process.EncoderProcess`)
  over python-can's ``udp_multicast`` interface on a port of its own per test — an interface
  that loops every frame back to its sender unmarked, so the driver must tell its own SYNC from
  another producer's;
- ``vcan``: the same over SocketCAN ``vcan`` (``HEXCAL_VCAN``, default vcan0, created with ``ip
  link`` when absent and permitted); skipped, with the reason, where the kernel has no CAN
  sockets;
- ``env``: a real channel, when

    HEXCAL_CAN_INTERFACE=socketcan HEXCAL_CAN_CHANNEL=vcan0 [HEXCAL_CAN_MOCK_CHANNEL=vcan0]

  is set (the mock nodes then answer on ``HEXCAL_CAN_MOCK_CHANNEL``, default the same channel).

Tests that need the virtual bus (injected error frames and bus-off, clock faults, replay onto a
virtual channel) are skipped elsewhere.

The core contract also runs against the mock EDS files (``device``): hexcal's generic one, and
the minimal, vendor-like and linear ones of :mod:`hexcal.mock_hw.eds_files`, written from the
CiA 301/406 object lists. On the virtual bus every device runs in the quick suite; in another
process a few tests run in the quick suite (QUICK_IN_PROCESS) and the whole contract, against
every device, under ``-m slow``.
"""

from __future__ import annotations

import itertools
import logging
import math
import os
import random
import re
import socket
import subprocess
import threading
import time
import uuid
from pathlib import Path

import can
import numpy as np
import pytest

from hexcal.acquire.acquisition import LegSample
from hexcal.drivers.can_config import CanBusConfig, LegEncoderConfig
from hexcal.drivers.can_encoders import (
    BusError,
    EncoderError,
    EncoderSilent,
    LegEncoders,
    ReadingSet,
    TpdoDecoder,
    decode_tpdo,
    describe_error_frame,
)
from hexcal.mock_hw.can_encoders import MockEncoderNodes
from hexcal.mock_hw.can_process import EncoderProcess
from hexcal.mock_hw.can_replay import replay_log
from hexcal.mock_hw.eds_files import mock_eds
from hexcal.mock_hw.robot import DEFAULT_NOISE, MockRobot
from hexcal.sim.robots import left_hand

SYNC_S = 0.01
#: The driver's default: heartbeats every 125 ms, so a node is reported silent only after the
#: host has stalled the mock's thread for 375 ms. At 0.2 s (50 ms heartbeats) a loaded CI machine
#: stalled every in-process mock node past it once, and a set was flagged for a silence nobody
#: injected.
HB_TIMEOUT_S = 0.5
# Mixed scales, signs and zeros, so the counts → mm conversion is really exercised.
CPM = [1000.0, 2000.0, 500.0, 1000.0, 4096.0, 1000.0]
SIGN = [1, -1, 1, -1, 1, -1]
ZERO = [0.0, 100.0, -25.5, 350.0, 0.125, -1000.0]
ENCODER_SIGMA_MM = DEFAULT_NOISE.sigma_reading_mm

ENV_INTERFACE = os.environ.get("HEXCAL_CAN_INTERFACE")
ENV_CHANNEL = os.environ.get("HEXCAL_CAN_CHANNEL")

#: Where the contract runs, and the object dictionaries of the devices (module docstring).
TARGETS = ["virtual", "udp", "vcan", "env"]
DEVICES = ["generic", "minimal", "vendor", "linear"]
#: Devices without 0x1019 take no SYNC counter; an UNSIGNED32 position takes no negative counts,
#: so its legs mounted the other way round (sign −1) have their zero beyond the leg's reach.
NO_COUNTER = ("minimal", "linear")
ZERO_UNSIGNED = [0.0, 2000.0, -25.5, 2350.0, 0.125, 3000.0]


def make_config(interface: str, channel: str, device: str = "generic", **kw) -> CanBusConfig:
    zero = ZERO_UNSIGNED if device == "minimal" else ZERO
    legs = [
        LegEncoderConfig(
            leg=k + 1, node_id=0x21 + k, counts_per_mm=CPM[k], sign=SIGN[k], zero_mm=zero[k]
        )
        for k in range(6)
    ]
    # SYNC with a counter where the device has 0x1019 (hexcal writes 240 to every node): the
    # contract matches each set to what the mock latched by its counter; without one, by its
    # number (latched_key). The rig file names the minimal and vendor-like devices' EDS (the
    # minimal one's position is UNSIGNED32; reading the vendor-like one's from the device, 0x1021,
    # is tested in test_drivers_can_devices.py); the linear one is set up from what it answers.
    base: dict = {"sync_period_s": SYNC_S, "heartbeat_timeout_s": HB_TIMEOUT_S}
    if device not in NO_COUNTER:
        base["sync_counter"] = 240
    if device in ("minimal", "vendor"):
        base["eds"] = str(mock_eds(device))
    return CanBusConfig(interface=interface, channel=channel, legs=legs, **{**base, **kw})


def unique_channel() -> str:
    # No trailing digits: python-can log writers read a trailing number as a channel number.
    return f"hexcal-test-{uuid.uuid4().hex[:8]}-bus"


def every_device(test):
    """Run ``test`` against every mock EDS (module docstring)."""
    test.contract_devices = True
    return test


#: The tests that run in another process in the quick suite too (each costs a process start,
#: about 1.5 s); the whole contract runs there under ``-m slow``.
QUICK_IN_PROCESS = {
    "test_readings_equal_the_robot_within_noise_and_quantisation",
    "test_dropped_frame_marks_that_set_incomplete",
    "test_another_sync_producer_is_flagged",
    "test_own_sync_looped_back_is_not_another_producer",
}


def pytest_generate_tests(metafunc):
    if "target" not in metafunc.fixturenames:
        return
    quick = metafunc.function.__name__ in QUICK_IN_PROCESS
    devices = DEVICES if getattr(metafunc.function, "contract_devices", False) else ["generic"]

    def slow(t: str, d: str) -> bool:
        return t in ("udp", "vcan") and (d != "generic" or not quick)

    combos = [
        pytest.param(
            t,
            d,
            marks=[pytest.mark.slow] if slow(t, d) else [],
            id=f"{t}-{d}" if len(devices) > 1 else t,
        )
        for t in TARGETS
        for d in devices
    ]
    if "device" in metafunc.fixturenames:
        metafunc.parametrize(("target", "device"), combos, indirect=True)
    else:  # builds its own nodes: the target alone
        metafunc.parametrize(
            "target",
            [pytest.param(c.values[0], marks=c.marks, id=c.id) for c in combos],
            indirect=True,
        )


def vcan_channel() -> str:
    """A SocketCAN vcan interface, created if absent and permitted; skips with the reason."""
    try:
        socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW).close()
    except (OSError, AttributeError) as exc:
        pytest.skip(
            f"SocketCAN vcan: this kernel has no CAN sockets (socket(AF_CAN, SOCK_RAW, CAN_RAW) "
            f"fails: {exc}), so there is no vcan; the contract runs over udp_multicast instead"
        )
    name = os.environ.get("HEXCAL_VCAN", "vcan0")
    if not Path(f"/sys/class/net/{name}").exists():
        made = subprocess.run(
            ["ip", "link", "add", "dev", name, "type", "vcan"], capture_output=True, text=True
        )
        if made.returncode:
            pytest.skip(
                f"SocketCAN vcan: `ip link add dev {name} type vcan` failed "
                f"({made.stderr.strip()}): load the vcan module (modprobe vcan) or create it"
            )
    up = subprocess.run(["ip", "link", "set", "up", name], capture_output=True, text=True)
    if up.returncode:
        pytest.skip(f"SocketCAN vcan: `ip link set up {name}` failed ({up.stderr.strip()})")
    return name


@pytest.fixture
def target(request) -> dict:
    """Where the contract runs (module docstring)."""
    kind = request.param
    if kind == "env":
        if not (ENV_INTERFACE and ENV_CHANNEL):
            pytest.skip("set HEXCAL_CAN_INTERFACE and HEXCAL_CAN_CHANNEL to run on a real channel")
        return {
            "interface": ENV_INTERFACE,
            "channel": ENV_CHANNEL,
            "mock_channel": os.environ.get("HEXCAL_CAN_MOCK_CHANNEL", ENV_CHANNEL),
            "virtual": False,
            "process": False,
            "options": {},
        }
    if kind == "udp":
        # A port of its own: on Linux a socket bound to a port receives that port's datagrams
        # for every group joined on the host, so the group alone would not keep tests apart.
        port = random.SystemRandom().randint(20_000, 60_000)
        return {
            "interface": "udp_multicast",
            "channel": "239.74.163.2",
            "mock_channel": "239.74.163.2",
            "virtual": False,
            "process": True,
            "options": {"port": port},
        }
    if kind == "vcan":
        name = vcan_channel()
        return {
            "interface": "socketcan",
            "channel": name,
            "mock_channel": name,
            "virtual": False,
            "process": True,
            "options": {},
        }
    ch = unique_channel()
    return {
        "interface": "virtual",
        "channel": ch,
        "mock_channel": ch,
        "virtual": True,
        "process": False,
        "options": {},
    }


@pytest.fixture
def device(request) -> str:
    """The mock EDS the nodes are built from (module docstring); hexcal's generic one unless the
    test runs against every device."""
    return getattr(request, "param", "generic")


def need_virtual(target: dict) -> None:
    if not target["virtual"]:
        pytest.skip("needs python-can's virtual bus (fault emulation or replay)")


def need_in_process(target: dict) -> None:
    if target["process"]:
        pytest.skip("builds its own mock nodes in this process")


class TwinRobot:
    """The robot of the encoders in another process, as the tests see it: a twin here (same
    design and seed) for what the tests compute, moved together with the child's."""

    def __init__(self, robot: MockRobot):
        self._robot = robot
        self.process: EncoderProcess | None = None

    def __getattr__(self, name: str):
        return getattr(self._robot, name)

    def move_to(self, position, rotation) -> None:
        assert self.process is not None
        self._robot.move_to(position, rotation)
        self.process.call("move_to", np.asarray(position).tolist(), np.asarray(rotation).tolist())


@pytest.fixture
def robot(target):
    twin = MockRobot(left_hand(), noise=DEFAULT_NOISE, seed=4)
    return TwinRobot(twin) if target["process"] else twin


@pytest.fixture
def config(target, device) -> CanBusConfig:
    return make_config(
        target["interface"], target["channel"], device, bus_options=target["options"]
    )


@pytest.fixture
def mock(robot, config, target, device):
    mock_cfg = config.model_copy(update={"channel": target["mock_channel"]})
    eds = None if device == "generic" else mock_eds(device)
    if target["process"]:
        nodes = EncoderProcess(mock_cfg, robot_seed=4, seed=1, eds=eds)
        robot.process = nodes
    else:
        nodes = MockEncoderNodes(robot, mock_cfg, seed=1, eds=eds)
    nodes.start()
    yield nodes
    nodes.stop()


def latched_key(s: ReadingSet) -> int:
    """The key of what the mock latched at ``s``'s SYNC: its counter, or, for SYNCs without
    one, its number since the mock started (1 for the driver's first)."""
    return s.sync_counter if s.sync_counter else s.index + 1


@pytest.fixture
def driver(mock, config):
    drv = LegEncoders(config)
    drv.start()
    yield drv
    drv.stop()


def read_sets(drv: LegEncoders, n: int) -> list[ReadingSet]:
    return [drv.read_set(timeout=1.0) for _ in range(n)]


def assert_contiguous(sets: list[ReadingSet]) -> None:
    """No set lost or reordered: indices step by one, SYNC counters by one modulo 240."""
    idx = [s.index for s in sets]
    assert idx == list(range(idx[0], idx[0] + len(idx)))
    for a, b in itertools.pairwise(sets):
        if a.sync_counter or b.sync_counter:  # 0: SYNC without a counter (the device's 0x1019)
            assert b.sync_counter == a.sync_counter % 240 + 1
        assert b.t_sync > a.t_sync


def assert_honest(s: ReadingSet) -> None:
    """A set is complete exactly when all six positions are there and nothing was reported."""
    assert s.complete == (bool(np.all(np.isfinite(s.readings_mm))) and not s.faults)
    assert np.array_equal(np.isfinite(s.readings_mm), np.isfinite(s.arrival))


#: Faults a busy computer can cause on its own (a thread stalled for a few ms): the driver must
#: flag them, and the tests accept them on sets they did not inject a fault into.
TIMING = (
    "ms after SYNC",
    "sent no position",
    "sent two positions",
    "outside any SYNC window",
    "SYNC producer",
)


def only_timing(s: ReadingSet) -> bool:
    return all(any(t in f for t in TIMING) for f in s.faults)


def read_complete(drv: LegEncoders, n: int, limit: int = 100) -> list[ReadingSet]:
    """Read until ``n`` complete sets; every other set read must be flagged for timing only."""
    sets = []
    while sum(s.complete for s in sets) < n:
        assert len(sets) < limit, f"fewer than {n} complete sets in {limit}"
        s = drv.read_set(timeout=1.0)
        assert_honest(s)
        assert s.complete or only_timing(s), s.faults
        sets.append(s)
    return sets


def read_until(drv: LegEncoders, pred, limit: int = 200) -> tuple[list[ReadingSet], ReadingSet]:
    """Read sets until one satisfies ``pred``; all sets read and that one."""
    seen = []
    for _ in range(limit):
        s = drv.read_set(timeout=1.0)
        seen.append(s)
        if pred(s):
            return seen, s
    raise AssertionError(f"no such set in {limit}: last faults {seen[-1].faults}")


# -- decoding, no bus ------------------------------------------------------------------------------
def test_decode_tpdo_applies_scale_sign_zero():
    cfg = make_config("virtual", "x")
    dec = TpdoDecoder(cfg)
    for k in range(6):
        leg = cfg.leg(k + 1)
        for counts in (0, 1, -1, 123_456, -2_000_000, 2**31 - 1, -(2**31)):
            msg = can.Message(
                arbitration_id=0x2A1 + k,
                data=counts.to_bytes(4, "little", signed=True),
                is_extended_id=False,
            )
            expected = SIGN[k] * counts / CPM[k] + ZERO[k]
            assert decode_tpdo(msg, cfg) == (k + 1, expected)
            assert dec.decode(msg) == (k + 1, expected)
            assert leg.counts_to_mm(counts) == expected
    # Extra mapped bytes after 0x6004 are ignored.
    msg = can.Message(
        arbitration_id=0x2A1, data=[0x10, 0x27, 0, 0, 9, 9, 9, 9], is_extended_id=False
    )
    assert decode_tpdo(msg, dec) == (1, 10.0)


def test_decode_tpdo_ignores_other_frames_and_rejects_short_ones():
    dec = TpdoDecoder(make_config("virtual", "x"))
    four = bytes(4)
    assert (
        dec.decode(can.Message(arbitration_id=0x2A7, data=four, is_extended_id=False)) is None
    )  # node 0x27
    assert dec.decode(can.Message(arbitration_id=0x721, data=[5], is_extended_id=False)) is None
    assert dec.decode(can.Message(arbitration_id=0x2A1, data=four, is_extended_id=True)) is None
    assert dec.decode(can.Message(arbitration_id=0x2A1, is_error_frame=True)) is None
    with pytest.raises(
        EncoderError,
        match=r"leg 1 encoder \(node 0x21\) sent a 2-byte TPDO2 .* check that node's TPDO2 mapping",
    ):
        dec.decode(can.Message(arbitration_id=0x2A1, data=[1, 2], is_extended_id=False))


def test_decode_batch_matches_scalar():
    dec = TpdoDecoder(make_config("virtual", "x"))
    rng = np.random.default_rng(0)
    ids = rng.choice([0x080, 0x2A1, 0x2A2, 0x2A3, 0x2A4, 0x2A5, 0x2A6, 0x721, 0x2A7], 500)
    counts = rng.integers(-(2**31), 2**31, 500)
    payload = np.zeros((500, 8), np.uint8)
    payload[:, :4] = counts.astype("<i4").view(np.uint8).reshape(500, 4)
    legs, mm = dec.decode_batch(ids, payload)
    for i in range(500):
        got = dec.decode(
            can.Message(arbitration_id=int(ids[i]), data=payload[i].tobytes(), is_extended_id=False)
        )
        if got is None:
            assert legs[i] == 0 and np.isnan(mm[i])
        else:
            assert legs[i] == got[0] and mm[i] == pytest.approx(got[1], rel=1e-15, abs=1e-12)


def test_describe_error_frames():
    def err(cid, data=bytes(8)):
        return can.Message(arbitration_id=cid, is_error_frame=True, data=data)

    assert describe_error_frame(err(0x040)) == "bus-off"
    assert describe_error_frame(err(0x088)) == "protocol violation, bus error"
    assert "error-passive" in describe_error_frame(err(0x004, bytes([0, 0x20, 0, 0, 0, 0, 0, 0])))
    assert describe_error_frame(err(0)) == "error frame"


# -- the contract: driver against the mock nodes --------------------------------------------------
@every_device
def test_nmt_start_and_heartbeats(driver, mock, config):
    for leg in config.legs:
        assert (0x01, leg.node_id) in mock.nmt_log  # started one by one, never by broadcast
    assert (0x01, 0) not in mock.nmt_log
    assert all(st == 0x05 for st in mock.states.values())
    st = driver.status()
    assert st["running"] and st["bus_state"] == "ACTIVE" and st["error_frames"] == 0
    assert [leg["nmt_state"] for leg in st["legs"]] == ["OPERATIONAL"] * 6
    assert all(leg["alive"] for leg in st["legs"])
    assert [leg["node_id"] for leg in st["legs"]] == list(range(0x21, 0x27))
    driver.check()  # all well: no exception


@every_device
def test_readings_equal_the_robot_within_noise_and_quantisation(driver, mock, robot, config):
    quantum = 0.5 / np.array(CPM)
    P, R = robot.true_pose()
    for step in range(2):
        if step:  # move the platform: the readings must follow
            P = P + np.array([1.0, -0.5, 3.0])
            robot.move_to(P, R)
            t_move = time.monotonic()
            read_until(driver, lambda s, t=t_move: s.t_sync > t)  # sets latched before the move go
        truth = robot.sim.readings(P[None], R[None])[0]
        sets = read_complete(driver, 20)
        assert_contiguous(sets)
        sets = [s for s in sets if s.complete]
        history = mock.latched()
        for s in sets:
            sent = history[latched_key(s)]  # what the mock latched at that SYNC, mm
            assert np.all(np.abs(s.readings_mm - sent) <= quantum + 1e-9)
            assert np.all(np.abs(s.readings_mm - truth) <= 6 * ENCODER_SIGMA_MM + quantum)
        # Noise is really there and really Gaussian-sized: not a constant, not wild.
        spread = np.std([s.readings_mm for s in sets], axis=0)
        assert np.all(spread > 0.2 * ENCODER_SIGMA_MM) and np.all(
            spread < 3 * ENCODER_SIGMA_MM + quantum
        )


@every_device
def test_sets_are_stamped_on_arrival(driver):
    t0 = time.monotonic()
    sets = read_complete(driver, 10)
    t1 = time.monotonic()
    for s in sets:
        assert t0 - 2 * SYNC_S < s.t_sync < t1
        got = np.isfinite(s.arrival)
        assert np.all(s.arrival[got] >= s.t_sync) and np.all(s.arrival[got] <= t1)
        assert s.readings_mm.shape == (6,) and s.arrival.shape == (6,)
        if s.complete:
            assert np.all(s.arrival - s.t_sync <= driver.config.tpdo_deadline_s)
    assert_contiguous(sets)
    assert driver.latest() is not None and driver.latest().index >= sets[-1].index


@every_device
def test_leg_source_for_acquisition(driver, mock):
    read_complete(driver, 1)
    s = driver.sample()
    assert isinstance(s, LegSample) and s.readings.shape == (6,)
    assert s.complete == (not s.faults)
    mock.drop_next(6)
    # The drop reaches the frames after the sets already queued: under a load of 10 on two
    # cores more than 20 sets were queued (CI's slow pass, once), so wait by the clock, not
    # by a count of sets (the loop ends at the first set the drop reaches).
    until = time.monotonic() + 5.0
    while True:
        s = driver.sample()
        seen = np.isnan(s.readings[5]) and np.all(np.isfinite(s.readings[:5]))
        if seen or time.monotonic() > until:
            break
    assert not s.complete and np.isnan(s.readings[5])
    assert any(f.startswith("leg 6 encoder (node 0x26) sent no position") for f in s.faults)


# -- faults ----------------------------------------------------------------------------------------
@every_device
def test_dropped_frame_marks_that_set_incomplete(driver, mock, config):
    read_complete(driver, 2)
    mock.drop_next(2)
    # The set the dropped frame left open (on a loaded machine a set before it may be flagged
    # for timing alone: not the one this test is about).
    before, bad = read_until(
        driver,
        lambda s: any(f.startswith("leg 2 encoder") and "sent no position" in f for f in s.faults),
    )
    after = read_complete(driver, 3)
    assert np.isnan(bad.readings_mm[1]) and np.isnan(bad.arrival[1]) and not bad.complete
    assert_honest(bad)
    for k in (0, 2, 3, 4, 5):  # the other legs' positions are kept, unless they too went missing
        assert np.isfinite(bad.readings_mm[k]) or any(
            f.startswith(f"leg {k + 1} encoder") for f in bad.faults
        )
    assert (
        f"leg 2 encoder (node 0x22) sent no position for SYNC {bad.sync_counter} on CAN "
        f"{config.interface} channel '{config.channel}': frame lost or late — set flagged incomplete; "
        "if it repeats check that node's cable and the bus termination"
    ) in bad.faults
    for s in before + after:
        assert_honest(s)
        assert s.complete or only_timing(s)
    assert_contiguous(before + after)
    assert driver.status()["legs"][1]["missing"] >= 1


@every_device
def test_silent_node_is_named_and_never_kept(driver, mock, config):
    read_complete(driver, 2)
    mock.silence(3)
    seen, flagged = read_until(driver, lambda s: any("silent" in f for f in s.faults))
    msg = next(f for f in flagged.faults if "silent" in f)
    assert msg.startswith("leg 3 encoder (node 0x23) silent for 0.")
    assert (
        f"on CAN {config.interface} channel '{config.channel}': "
        f"no heartbeat (timeout {HB_TIMEOUT_S:g} s)" in msg
    )
    assert "check that encoder's power and cable" in msg
    assert np.isnan(flagged.readings_mm[2]) and not flagged.complete
    with pytest.raises(EncoderSilent, match=r"leg 3 encoder \(node 0x23\) silent for") as exc:
        driver.check()
    assert exc.value.legs == (3,) and exc.value.node_ids == (0x23,)
    st = driver.status()["legs"][2]
    assert not st["alive"] and st["heartbeat_age_s"] > HB_TIMEOUT_S
    mock.silence(3, False)  # cable back: heartbeats and positions resume
    more, _ = read_until(driver, lambda s: s.complete)
    for s in seen + more:
        assert_honest(s)
        if np.isnan(s.readings_mm[2]):
            assert not s.complete
    assert_contiguous(seen + more)
    driver.check()


@every_device
def test_jitter_flags_late_positions(driver, mock):
    read_complete(driver, 2)
    mock.jitter_s = 0.9 * SYNC_S  # deadline is half a SYNC period
    sets = read_sets(driver, 40)
    mock.jitter_s = 0.0
    late = [s for s in sets if any("ms after SYNC" in f for f in s.faults)]
    assert late, "no late position flagged"
    msg = next(f for f in late[0].faults if "ms after SYNC" in f)
    assert (
        "(limit 5.0 ms)" in msg
        and "timing jitter or bus overload" in msg
        and "encoder (node 0x2" in msg
    )
    for s in sets:
        assert_honest(s)
        delays = s.arrival - s.t_sync
        if np.any(delays > driver.config.tpdo_deadline_s):
            assert not s.complete
    assert_contiguous(sets)


def test_error_frames_flag_the_set(driver, mock, config, target):
    need_virtual(target)
    read_sets(driver, 2)
    mock.error_frames(3)
    _, bad = read_until(driver, lambda s: any("error frame" in f for f in s.faults))
    msg = next(f for f in bad.faults if "error frame" in f)
    assert msg.startswith(
        f"CAN error frame on CAN virtual channel '{config.channel}' (protocol violation, bus error;"
    )
    assert "check the 120 Ω termination" in msg and "1000 kbit/s" in msg
    assert not bad.complete
    deadline = time.monotonic() + 1.0
    while driver.status()["error_frames"] < 3 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert driver.status()["error_frames"] == 3 and driver.status()["bus_state"] == "ACTIVE"
    read_until(driver, lambda s: s.complete)  # errors stop, sets are clean again


def test_bus_off_is_reported_and_recovered(driver, mock, config, target):
    need_virtual(target)
    read_sets(driver, 2)
    mock.bus_off()
    seen, bad = read_until(driver, lambda s: any("BUS-OFF" in f for f in s.faults))
    msg = next(f for f in bad.faults if "BUS-OFF" in f)
    assert msg.startswith(f"CAN virtual channel '{config.channel}' is BUS-OFF")
    assert (
        "check the cable, the 120 Ω termination at both ends" in msg
        and "restart acquisition" in msg
    )
    assert driver.status()["bus_state"] == "BUS-OFF"
    with pytest.raises(BusError, match="is BUS-OFF") as exc:
        driver.check()
    assert exc.value.state == "BUS-OFF"
    more = read_sets(driver, 5)
    assert not any(s.complete for s in more)  # nothing taken during the fault is kept as good
    assert all(np.all(np.isnan(s.readings_mm)) for s in more)
    mock.recover()
    again, _ = read_until(driver, lambda s: s.complete)
    assert driver.status()["bus_state"] == "ACTIVE"
    assert_contiguous(seen + more + again)


@every_device
def test_rebooted_node_is_restarted(driver, mock):
    read_sets(driver, 2)
    n_start = mock.nmt_log.count((0x01, 0x24))
    mock.reboot(4)
    seen, bad = read_until(driver, lambda s: any("rebooted" in f for f in s.faults))
    assert any(
        f.startswith("leg 4 encoder (node 0x24) rebooted (boot-up message on CAN")
        for f in bad.faults
    )
    more, _ = read_until(driver, lambda s: s.complete)
    assert mock.nmt_log.count((0x01, 0x24)) > n_start  # the driver sent NMT start again
    assert_contiguous(seen + more)


def test_a_node_sent_to_pre_operational_is_started_again(driver, mock, config):
    """Another NMT master sends leg 4's node to PRE-OPERATIONAL (no boot-up: it keeps its
    settings): its heartbeat says so, a set is flagged with that state, and the driver starts
    it again (NMT start), so complete sets follow."""
    read_sets(driver, 2)
    n_start = mock.nmt_log.count((0x01, 0x24))
    with can.Bus(**config.bus_kwargs()) as other:
        other.send(can.Message(arbitration_id=0x000, data=[0x80, 0x24], is_extended_id=False))
    seen, bad = read_until(driver, lambda s: any("PRE-OPERATIONAL" in f for f in s.faults))
    assert any(
        f.startswith("leg 4 encoder (node 0x24) reports NMT state PRE-OPERATIONAL")
        for f in bad.faults
    )
    more, _ = read_until(driver, lambda s: s.complete)
    assert mock.nmt_log.count((0x01, 0x24)) > n_start  # the driver sent NMT start again
    assert_contiguous(seen + more)


def test_another_sync_producer_is_flagged(driver, config, target):
    """Another master's SYNC is flagged — also where the driver's own SYNCs come back unmarked
    (udp_multicast), which must not be (test_own_sync_looped_back_is_not_another_producer)."""
    read_sets(driver, 2)
    with can.Bus(**config.bus_kwargs()) as other:
        other.send(can.Message(arbitration_id=0x80, data=[], is_extended_id=False))
    _, bad = read_until(driver, lambda s: any("another SYNC producer" in f for f in s.faults))
    assert not bad.complete and driver.status()["foreign_syncs"] == 1


def test_own_sync_looped_back_is_not_another_producer(driver, target):
    """Every SYNC the driver sends comes back to it on udp_multicast, unmarked (python-can cannot
    set receive_own_messages there): none may be taken for another producer's, and each gives
    its set the SYNC's wire time."""
    sets = read_complete(driver, 100, limit=130)
    st = driver.status()
    assert st["foreign_syncs"] == 0
    assert not any("SYNC producer" in f for s in sets for f in s.faults)
    assert st["sync_sent"] >= len(sets)


#: The jumps as the driver tells them, to the ms (a frame's own latency moves the last digits).
HOUR, THOUSAND = r"3(599|600)\.\d{3}", r"(999|1000)\.\d{3}"
#: Sets after a bus clock fault that may be flagged before attribution is right again: the
#: fault's own SYNC, the ones the driver takes to confirm a jump (two periods), the re-anchoring.
RECOVERY_SETS = 6


@pytest.mark.parametrize(
    "inject, said, jumps",
    [
        (lambda nodes: nodes.stamp_next(4, 3600.0), rf"1 frame\(s\) stamped \+{HOUR} s off", 0),
        (lambda nodes: nodes.step_clock(3600.0), rf"clock of .* jumped \+{HOUR} s", 1),
        (lambda nodes: nodes.step_clock(-1000.0), rf"clock of .* jumped -{THOUSAND} s", 1),
    ],
    ids=["one frame stamped an hour ahead", "clock steps an hour ahead", "clock reset back"],
)
def test_a_bus_clock_jump_costs_a_few_sets_then_sets_are_complete_again(
    robot, target, inject, said, jumps, caplog
):
    """One frame stamped an hour off, or the interface's clock stepping for good (forward, or
    reset back): the driver flags the sets it cannot place positions in, re-anchors within a
    few SYNC periods, says so once in the log naming the bus, and every later set is complete."""
    need_virtual(target)
    cfg = make_config("virtual", unique_channel())
    with (
        caplog.at_level(logging.INFO, logger="hexcal.drivers.can_encoders"),
        MockEncoderNodes(robot, cfg) as nodes,
        LegEncoders(cfg) as drv,
    ):
        read_complete(drv, 3)
        inject(nodes)
        sets = read_sets(drv, RECOVERY_SETS + 40)
        status = drv.status()
    assert_contiguous(sets)
    later = sets[RECOVERY_SETS:]
    assert sum(s.complete for s in later) >= 35, [s.faults for s in later if not s.complete]
    assert all(s.complete or only_timing(s) for s in later)
    hit = [s for s in sets[:RECOVERY_SETS] if not s.complete]
    assert any("off the clock of" in f or "jumped" in f for s in hit for f in s.faults)
    told = [r for r in caplog.records if re.search(said, r.getMessage())]
    assert len(told) == 1 and told[0].levelno == logging.WARNING
    assert cfg.channel in told[0].getMessage()
    assert status["clock_jumps"] == jumps


def test_a_non_finite_reading_is_a_fault_of_its_set(robot, target):
    """Counts that the leg's scaling turns into no finite number (a counts_per_mm of 1e-320
    typed by mistake) flag the set, naming the leg; no NaN or inf becomes a reading."""
    need_virtual(target)
    cfg = make_config("virtual", unique_channel())
    legs = [
        leg.model_copy(update={"counts_per_mm": 1e-320}) if leg.leg == 2 else leg
        for leg in cfg.legs
    ]
    mock_cfg = cfg  # the nodes send sane counts; only the driver's scaling is wrong
    drv_cfg = cfg.model_copy(update={"legs": legs})
    with MockEncoderNodes(robot, mock_cfg), LegEncoders(drv_cfg) as drv:
        sets = read_sets(drv, 5)
    for s in sets:
        assert not s.complete and np.isnan(s.readings_mm[1])
        assert np.all(np.isfinite(s.readings_mm) | np.isnan(s.readings_mm))
        assert any(
            "leg 2 encoder (node 0x22) sent" in f and "no finite reading" in f for f in s.faults
        )
    dec = TpdoDecoder(drv_cfg)
    msg = can.Message(
        arbitration_id=0x2A2, data=(123456).to_bytes(4, "little"), is_extended_id=False
    )
    with pytest.raises(EncoderError, match="no finite reading"):
        dec.decode(msg)
    legs_b, mm_b = dec.decode_batch(np.array([0x2A2]), np.frombuffer(msg.data, np.uint8)[None])
    assert legs_b[0] == 2 and np.isnan(mm_b[0])


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"heartbeat_timeout_s": math.inf}, "heartbeat_timeout_s"),
        ({"heartbeat_timeout_s": 3600.0}, "heartbeat_timeout_s"),
        ({"sync_period_s": 61.0}, "sync_period_s"),
    ],
)
def test_config_durations_are_bounded(kwargs, name):
    with pytest.raises(ValueError, match=name):
        make_config("virtual", "x", **kwargs)
    # A config built past validation is caught by the driver itself.
    cfg = make_config("virtual", "x").model_copy(update=kwargs)
    with pytest.raises(ValueError, match=rf"{name} must be a finite number of seconds"):
        LegEncoders(cfg)


@pytest.mark.parametrize("bad", [math.inf, math.nan, -1.0, 61.0, 1e300])
def test_driver_timeouts_are_bounded(bad):
    cfg = make_config("virtual", unique_channel())
    with pytest.raises(ValueError, match="clock_jump_s must be a finite number of seconds"):
        LegEncoders(cfg, clock_jump_s=bad)
    drv = LegEncoders(cfg)
    with pytest.raises(ValueError, match="timeout must be a finite number of seconds"):
        drv.start(timeout=bad)
    with pytest.raises(ValueError, match="timeout must be a finite number of seconds"):
        drv.read_set(timeout=bad)
    assert not drv.status()["running"]


def test_start_names_a_node_that_never_answers(robot, config, target):
    """A node silent from the start: the configuration step gets no SDO answer from it (and
    names every such node); without configuration, no heartbeat after NMT start."""
    mock_cfg = config.model_copy(update={"channel": target["mock_channel"]})
    with MockEncoderNodes(robot, mock_cfg) as nodes:
        nodes.silence(5)
        nodes.silence(2)
        drv = LegEncoders(config)
        threads = threading.active_count()
        with pytest.raises(
            EncoderSilent, match=r"leg 2 encoder \(node 0x22\) .*: no SDO answer"
        ) as exc:
            drv.start(timeout=0.15)
        assert exc.value.legs == (2, 5)
        assert "check that it is powered, wired to this bus, has node id 0x25" in str(exc.value)
        assert threading.active_count() <= threads  # nothing left running
        assert not drv.status()["running"]
        nodes.silence(2, False)
        # Taken as configured (can.configure = false): only NMT start. The attempt above set
        # up the four nodes that answered; nodes 2 and 5 are still at their factory settings,
        # heartbeat off, so they are not heard — and the message says to check the heartbeat
        # producer.
        bare = LegEncoders(config.model_copy(update={"configure": False}))
        with pytest.raises(
            EncoderSilent, match=r"leg 5 encoder \(node 0x25\) silent for 0\.\d s after NMT start"
        ) as exc:
            bare.start(timeout=0.15)
    assert exc.value.legs == (2, 5)
    assert "powered and wired to this bus" in str(exc.value)
    assert "the heartbeat producer (object 0x1017) is on" in str(exc.value)


def test_unknown_interface_is_a_bus_error():
    cfg = make_config("no-such-interface", "x")
    with pytest.raises(
        BusError,
        match=r"could not open CAN no-such-interface channel 'x' at 1000 kbit/s: .*check the interface name",
    ):
        LegEncoders(cfg).start()


def test_no_sync_producer_times_out_clearly(mock, config):
    follower = config.model_copy(update={"sync_period_s": 0.0})
    with LegEncoders(follower) as drv:
        with pytest.raises(
            EncoderError,
            match=r"no reading set from CAN .* in 0.1 s: no SYNC seen — is the master producing SYNC\?",
        ):
            drv.read_set(timeout=0.1)


def test_stop_keeps_unread_sets(mock, config):
    drv = LegEncoders(config).start()
    time.sleep(10 * SYNC_S)
    drv.stop()
    left = []
    with pytest.raises(EncoderError, match="is stopped and every reading set has been read"):
        while True:
            left.append(drv.read_set(timeout=0.1))
    assert len(left) >= 5
    assert_contiguous(left)
    assert all(s.complete or s.faults for s in left)


# -- record and replay -----------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", [".asc", ".blf"])
def test_replayed_log_decodes_to_the_same_readings(tmp_path, robot, target, suffix):
    """Record a run (with one dropped frame) to a python-can log, replay the log onto a fresh
    virtual bus, decode it with a listen-only driver: the same sets, flags included."""
    need_virtual(target)
    cfg = make_config("virtual", unique_channel())
    path = tmp_path / f"run{suffix}"
    with MockEncoderNodes(robot, cfg) as nodes, LegEncoders(cfg, log_path=path) as drv:
        live = read_complete(drv, 5)
        nodes.drop_next(5)
        live += read_sets(drv, 8)
    dropped = [s for s in live if np.isnan(s.readings_mm[4])]
    assert dropped

    replay_cfg = cfg.model_copy(update={"channel": unique_channel()})
    with LegEncoders(replay_cfg, listen_only=True) as listener:
        assert replay_log(path, replay_cfg) > 13 * 7  # every SYNC and TPDO, and more
        replayed = {}
        # Read until every live SYNC is seen, waiting by the clock (10 s), not by the first
        # 0.3 s without a set: on a loaded machine the listener's thread lags the replay.
        want = {s.sync_counter for s in live}
        until = time.monotonic() + 10.0
        while not want <= replayed.keys() and time.monotonic() < until:
            try:
                s = listener.read_set(timeout=0.3)
            except EncoderError:
                continue
            replayed[s.sync_counter] = s
    assert not any(m["nmt_state"] != "OPERATIONAL" for m in listener.status()["legs"])
    for s in live:  # same SYNCs, same positions in them (NaN where none came), bit for bit
        np.testing.assert_array_equal(replayed[s.sync_counter].readings_mm, s.readings_mm)
    for s in dropped:
        r = replayed[s.sync_counter]
        assert not r.complete and any(
            f.startswith("leg 5 encoder (node 0x25) sent no position") for f in r.faults
        )


def test_replay_names_a_missing_or_unreadable_log(tmp_path):
    cfg = make_config("virtual", unique_channel())
    with pytest.raises(FileNotFoundError, match=r"nope\.blf: no such CAN log"):
        replay_log(tmp_path / "nope.blf", cfg)
    odd = tmp_path / "run.xyz"
    odd.write_text("not a log")
    with pytest.raises(ValueError, match=r"run\.xyz: python-can cannot read this log format"):
        replay_log(odd, cfg)


# -- attribution under stalls ----------------------------------------------------------------------
class _Mover:
    """Moves the robot a little every 2 ms, so every SYNC latches clearly different readings and
    a position kept in the wrong set cannot pass for the right one."""

    def __init__(self, robot: MockRobot):
        self.robot = robot
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.home_p, self.home_r = robot.true_pose()

    def run(self) -> None:
        i = 0
        while not self.stop.wait(0.002):
            i += 1
            dz = 2.0 * np.sin(i / 5.0)  # mm: about 0.4 mm between SYNCs 10 ms apart
            self.robot.move_to(self.home_p + [0.0, 0.0, dz], self.home_r)


#: Chance that handling a frame (driver) or a SYNC (mock) stalls for 0.5 to 1.5 SYNC periods.
STALL_P = {"driver": 0.05, "mock": 0.25}


@pytest.mark.parametrize("who", ["driver", "mock"])
def test_a_stalled_thread_never_puts_a_position_in_the_wrong_set(robot, target, who, monkeypatch):
    """A busy computer stalls the driver's receive thread (or the mock nodes' thread) for more
    than a SYNC period now and then. Every set marked complete must still hold exactly the
    positions latched at its own SYNC; sets the stall damaged are flagged, none is lost."""
    need_virtual(target)
    cfg = make_config("virtual", unique_channel())
    rng = np.random.default_rng(7)
    mover = _Mover(robot)
    with MockEncoderNodes(robot, cfg) as nodes, LegEncoders(cfg) as drv:
        victim, name = (drv, "_dispatch") if who == "driver" else (nodes, "_on_sync")
        inner = getattr(victim, name)

        def stalling(*args, **kwargs):
            if rng.random() < STALL_P[who]:
                time.sleep(rng.uniform(0.5, 1.5) * SYNC_S)
            return inner(*args, **kwargs)

        monkeypatch.setattr(victim, name, stalling)
        mover.thread.start()
        try:
            sets = read_sets(drv, 150)
        finally:
            mover.stop.set()
            mover.thread.join()
        latched = nodes.latched()
    assert_contiguous(sets)
    complete = [s for s in sets if s.complete]
    assert len(complete) > 30, f"only {len(complete)} of 150 sets complete"
    quantum = 0.5 / np.array(CPM) + 1e-9
    for s in sets:
        assert_honest(s)
        assert s.complete or only_timing(s), s.faults
        if s.complete:
            err = np.abs(s.readings_mm - latched[s.sync_counter])
            assert np.all(err <= quantum), (s.index, s.sync_counter, err)
    # The robot moved between SYNCs: a position from the neighbouring SYNC would have been seen.
    steps = [np.abs(latched[c % 240 + 1] - latched[c]).max() for c in list(latched)[:-1]]
    assert np.median(steps) > 50 * quantum.max()


@pytest.mark.parametrize("echo", [True, False], ids=["echoed", "no echo"])
@pytest.mark.parametrize("stall_s", [0.7 * SYNC_S, 15 * SYNC_S], ids=["0.7 period", "15 periods"])
def test_a_sync_sent_late_by_a_busy_host_flags_no_set(robot, target, echo, stall_s):
    """The SYNC producer stamps its set, then a busy host stalls it before the SYNC goes on the
    wire: for more than the 5 ms answer deadline, or for longer than a quiet bus takes to close
    a set by time (0.12 s). Its answers are on time (0.1 ms after the wire time): no set may be
    flagged. With the SYNC's echo (``receive_own_messages``) the set takes the SYNC's wire
    time; on a bus without echoes, the time the send returned bounds it."""
    need_virtual(target)
    cfg = make_config("virtual", unique_channel())
    rng = np.random.default_rng(3)
    bus = None if echo else can.Bus(interface="virtual", channel=cfg.channel)
    try:
        with MockEncoderNodes(robot, cfg) as nodes, LegEncoders(cfg, bus=bus) as drv:
            sync = drv._network.sync
            inner = sync.transmit

            def stalled(*args, **kwargs):
                if rng.random() < 0.3:
                    time.sleep(stall_s)
                return inner(*args, **kwargs)

            sync.transmit = stalled
            sets = read_sets(drv, 40)
            latched = nodes.latched()
    finally:
        if bus is not None:
            bus.shutdown()
    assert_contiguous(sets)
    assert [s.faults for s in sets if not s.complete] == []
    quantum = 0.5 / np.array(CPM) + 1e-9
    for s in sets:
        assert np.all(np.abs(s.readings_mm - latched[s.sync_counter]) <= quantum)


def test_answers_a_busy_host_holds_back_close_no_set_by_time(robot, target):
    """The answers to two SYNCs reach the driver 0.3 s late (the simulated nodes' thread held
    back, as a receive thread on a loaded machine can be), though stamped on time: no set may
    be closed by time as if the bus had gone quiet — a set waits as long as a node may be
    quiet before it is reported silent (heartbeat_timeout_s)."""
    need_virtual(target)
    cfg = make_config("virtual", unique_channel(), heartbeat_timeout_s=0.5)
    nodes = MockEncoderNodes(robot, cfg)
    inner = nodes._on_sync
    seen = itertools.count()

    def held_back(*args, **kwargs):
        if next(seen) in (20, 60):
            time.sleep(0.3)
        return inner(*args, **kwargs)

    nodes._on_sync = held_back  # type: ignore[method-assign]  # before start() subscribes it
    with nodes, LegEncoders(cfg) as drv:
        sets = read_sets(drv, 100)
    assert_contiguous(sets)
    assert [s.faults for s in sets if not s.complete] == []


@pytest.mark.parametrize("period", [5e-324, 1e-6, 0.0009])
def test_a_sync_period_no_bus_can_carry_is_refused_by_name(period):
    """Found by the fuzzing pass: a denormal period passed, and half of it (the answers'
    deadline) was 0. A SYNC period is 0 (another master) or at least 1 ms."""
    with pytest.raises(ValueError, match=r"sync_period_s is 0 .* or at least 1 ms"):
        make_config("virtual", "x", sync_period_s=period)
    assert make_config("virtual", "x", sync_period_s=0.001).tpdo_deadline_s == 0.0005
