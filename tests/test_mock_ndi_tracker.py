"""The mock NDI tracker on its own: the protocol state machine byte for byte, its faults, the
pyserial URL handler and the pty bridge. (The driver against it: test_drivers_ndi.py.)

The replies are checked against the documented format with this file's own regular expressions,
not with the driver's parser, so that the two cannot share a mistake.
"""

from __future__ import annotations

import itertools
import os
import re
import struct
import time

import numpy as np
import pytest
import serial

from hexcal.drivers.crc import crc16, crc16_hex
from hexcal.mock_hw.ndi_registry import device_for_url, get_device, register_robot, unregister
from hexcal.mock_hw.ndi_tracker import (
    FaultSettings,
    MockNDITracker,
    ToolState,
    format_bx_reply,
    format_tx_reply,
)
from hexcal.mock_hw.pty_tracker import PtyTracker
from hexcal.mock_hw.robot import MockRobot
from hexcal.sim.robots import left_hand
from hexcal.sim.simulate import NoiseModel

TX_POSE = re.compile(
    rb"01(01)([+-]\d{5})([+-]\d{5})([+-]\d{5})([+-]\d{5})([+-]\d{6})([+-]\d{6})([+-]\d{6})"
    rb"([+-]\d{5})([0-9A-F]{8})([0-9A-F]{8})\n([0-9A-F]{4})([0-9A-F]{4})\r"
)
_names = itertools.count()


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def cmd(text: str) -> bytes:
    """A command as a host sends it: NAME:params + CRC + CR, or NAME params + CR."""
    data = text.encode()
    return data + (crc16_hex(data) if b":" in data else b"") + b"\r"


def ask(dev: MockNDITracker, text: str, baud: int | None = None, timeout: float = 0.5) -> bytes:
    dev.feed(cmd(text), host_baud=baud)
    return dev.read(100_000, timeout)


def ok_crc(reply: bytes) -> bool:
    return reply.endswith(b"\r") and crc16_hex(reply[:-5]) == reply[-5:-1]


@pytest.fixture
def robot():
    return MockRobot(left_hand(), noise=NoiseModel(0.01, 0.002, 0.0), seed=5)


@pytest.fixture
def dev(robot):
    return MockNDITracker(robot, seed=5, frame_rate_hz=1000.0)


def tracking(dev: MockNDITracker) -> MockNDITracker:
    for text in ("INIT:", "PINIT:01", "PENA:01D", "TSTART:"):
        assert ask(dev, text) == b"OKAY" + crc16_hex(b"OKAY") + b"\r", text
    return dev


# -- the protocol ----------------------------------------------------------------------------------
def test_break_and_reset_command_answer_resetbe6f(dev):
    dev.on_break()
    assert dev.read(100, 0.1) == b"RESETBE6F\r"
    assert ask(dev, "RESET 0") == b"RESETBE6F\r"  # the space form carries no CRC
    assert ask(dev, "RESET:0") == b"RESETBE6F\r"
    assert dev.baud == 9600 and not dev.initialized


def test_command_crc_is_checked(dev):
    assert ask(dev, "INIT:") == b"OKAY" + crc16_hex(b"OKAY") + b"\r"
    dev.feed(b"INIT:0000\r")
    reply = dev.read(100, 0.1)
    assert reply.startswith(b"ERROR04") and ok_crc(reply)


@pytest.mark.parametrize(
    "setup, text, code",
    [
        ((), "TX:0001", b"ERROR10"),  # before INIT
        (("INIT:",), "FOO:", b"ERROR01"),
        (("INIT:",), "TX:0001", b"ERROR0C"),  # not tracking
        (("INIT:",), "TSTOP:", b"ERROR0C"),
        (("INIT:",), "PENA:01D", b"ERROR0E"),  # not initialised
        (("INIT:", "PINIT:01"), "PENA:01X", b"ERROR09"),
        (("INIT:",), "PINIT:07", b"ERROR08"),
        ((), "COMM:90000", b"ERROR06"),
        (("INIT:", "PINIT:01", "PENA:01D", "TSTART:"), "TSTART:", b"ERROR0C"),
    ],
)
def test_errors_a_tracker_gives(dev, setup, text, code):
    for s in setup:
        ask(dev, s)
    reply = ask(dev, text)
    assert reply[:7] == code and ok_crc(reply)


def test_phsr_lists_handles_by_state(dev):
    ask(dev, "INIT:")
    assert ask(dev, "PHSR:02")[:-5] == b"0101001"
    assert ask(dev, "PHSR:04")[:-5] == b"00"
    ask(dev, "PINIT:01")
    assert ask(dev, "PHSR:03")[:-5] == b"0101011"
    ask(dev, "PENA:01D")
    assert ask(dev, "PHSR:04")[:-5] == b"0101031"
    assert ask(dev, "PHSR:01")[:-5] == b"00"


def test_comm_switches_baud_and_a_wrong_rate_loses_the_bytes(dev):
    assert ask(dev, "COMM:50000", baud=9600)[:4] == b"OKAY"
    assert dev.baud == 115200
    assert ask(dev, "INIT:", baud=9600, timeout=0.05) == b""  # framing errors: nothing understood
    assert dev.framing_errors == 1
    assert ask(dev, "INIT:", baud=115200)[:4] == b"OKAY"


def test_tx_reply_format_and_values(dev, robot):
    tracking(dev)
    reply = ask(dev, "TX:0001")
    m = TX_POSE.fullmatch(reply)
    assert m, reply
    assert crc16_hex(reply[:-5]) == m.group(13)
    p, q, rms = dev.last_sent[1]
    g = m.groups()
    np.testing.assert_allclose([int(v) * 1e-4 for v in g[1:5]], q, atol=0.5e-4 + 1e-12)
    np.testing.assert_allclose([int(v) * 0.01 for v in g[5:8]], p, atol=0.005 + 1e-9)
    assert int(g[8]) * 1e-4 == pytest.approx(rms, abs=0.5e-4)
    assert int(g[9], 16) == 0x31 and int(g[11], 16) == 0


def test_one_measurement_per_frame(robot):
    clock = FakeClock()
    dev = tracking(MockNDITracker(robot, frame_rate_hz=60.0, clock=clock))
    a, b = ask(dev, "TX:0001"), ask(dev, "TX:0001")
    assert a == b  # same frame: same reading, as from a real tracker
    # Into the next frame: a TX command (12 bytes at 9600 baud) takes effect 12.5 ms after it
    # is written, 0.75 of a frame, so 1.75 frames after frame 1 began.
    clock.t += 1.0 / 60
    c = ask(dev, "TX:0001")
    assert (
        c != a
        and int(TX_POSE.fullmatch(c).group(11), 16) == int(TX_POSE.fullmatch(a).group(11), 16) + 1
    )


def test_frame_is_measured_at_its_boundary_as_of_the_command():
    """Frame n is the robot's pose at t0 + (n - 1) / rate, whenever polled; a command acts as of
    its arrival (its bytes at the line's baud rate), even when the host reads the reply late;
    ``frame_times`` records each frame's true instant."""
    clock = FakeClock()
    robot = MockRobot(left_hand(), noise=NoiseModel(0.0, 0.0, 0.0), clock=clock)
    dev = tracking(MockNDITracker(robot, frame_rate_hz=60.0, clock=clock))  # 9600 baud
    home, _ = robot.true_pose()
    boundary = dev.frame_time(10)
    assert boundary == pytest.approx(100.0 + 9 / 60)
    clock.t = boundary + 0.001  # frame 10 was exposed 1 ms ago...
    robot.move_to(home + [0.0, 0.0, 5.0], np.eye(3))  # ...then the platform jumped 5 mm
    reply = ask(dev, "TX:0001")  # 12 bytes at 9600 baud: acts 12.5 ms later, still frame 10
    m = TX_POSE.fullmatch(reply)
    assert int(m.group(11), 16) == 10
    assert int(m.group(8)) * 0.01 == pytest.approx(home[2], abs=0.006)  # the pose at exposure
    assert (10, boundary) in dev.frame_times
    dev.feed(cmd("TX:0001"))  # sent within frame 10 ...
    clock.t += 5 / 60  # ... but read five frames later: still frame 10, as on a real line
    assert int(TX_POSE.fullmatch(dev.read(100_000, 0.5)).group(11), 16) == 10
    reply = ask(dev, "TX:0001")  # now: frame 15, exposed after the jump
    m = TX_POSE.fullmatch(reply)
    assert int(m.group(11), 16) == 15
    assert int(m.group(8)) * 0.01 == pytest.approx(home[2] + 5.0, abs=0.006)
    assert [n for n, _ in dev.frame_times] == [10, 15]
    assert dict(dev.frame_times)[15] == pytest.approx(dev.frame_time(15))


def test_a_command_is_answered_after_it_crossed_the_line(dev):
    """Nothing comes back before the command itself has arrived: 12 bytes at 9600 baud take
    12.5 ms (a lower bound on the wait, not a speed requirement)."""
    tracking(dev)
    t0 = time.monotonic()
    dev.feed(cmd("TX:0001"))
    assert dev.read(100_000, 0.0) == b""
    assert TX_POSE.fullmatch(dev.read(100_000, 1.0))
    assert time.monotonic() - t0 >= 12 * 10 / 9600


def test_missing_and_out_of_volume(dev, robot):
    tracking(dev)
    robot.tool_visible = False
    reply = ask(dev, "TX:0001")
    assert re.fullmatch(rb"0101MISSING00000031[0-9A-F]{8}\n0000[0-9A-F]{4}\r", reply)
    robot.tool_visible = True
    robot.move_to([0.0, 0.0, 3500.0], np.eye(3))
    time.sleep(0.002)  # next frame
    # Outside the volume a tracker does not normally report the transform: MISSING, with the
    # out-of-volume bit; reply option 0x0800 asks for it, and the pose comes with the bit.
    reply = ask(dev, "TX:0001")
    assert re.fullmatch(rb"0101MISSING00000071[0-9A-F]{8}\n0000[0-9A-F]{4}\r", reply), reply
    m = TX_POSE.fullmatch(ask(dev, "TX:0801"))
    assert int(m.group(10), 16) == 0x31 | 0x40 and abs(int(m.group(8)) - 350000) < 10  # z
    robot.move_to([0.0, 0.0, 2980.0], np.eye(3))
    time.sleep(0.002)
    for option in ("0001", "0801"):  # partly out: reported with or without the option
        assert int(TX_POSE.fullmatch(ask(dev, f"TX:{option}")).group(10), 16) == 0x31 | 0x80


def test_bx_reply_format(dev):
    tracking(dev)
    reply = ask(dev, "BX:0001")
    assert reply[:2] == b"\xc4\xa5"
    length, hcrc = struct.unpack_from("<HH", reply, 2)
    assert hcrc == crc16(reply[:4]) and len(reply) == 6 + length + 2
    body = reply[6:-2]
    assert struct.unpack("<H", reply[-2:])[0] == crc16(body)
    assert body[:3] == b"\x01\x01\x01"
    values = struct.unpack_from("<8f", body, 3)
    p, q, rms = dev.last_sent[1]
    np.testing.assert_allclose(values[:4], q, atol=1e-6)
    np.testing.assert_allclose(values[4:7], p, rtol=1e-6)
    assert values[7] == pytest.approx(rms, rel=1e-6)
    status, _frame = struct.unpack_from("<II", body, 35)
    assert status == 0x31 and struct.unpack_from("<H", body, 43)[0] == 0 and len(body) == 45


def test_formatters_missing_disabled_and_saturation():
    tools = [
        ToolState(1, (np.array([1e6, -1.0, 0.0]), np.array([1.0, 0, 0, 0]), 0.2), 0x31, 7),
        ToolState(2, None, 0x31, 7),
        ToolState(3, None, 0, 0, disabled=True),
    ]
    payload = format_tx_reply(tools, 0x0010)[:-5]
    assert payload.split(b"\n")[0][2:].startswith(
        b"01+10000+00000+00000+00000+999999-000100+000000+02000"
    )
    assert payload.split(b"\n")[1:] == [b"02MISSING0000003100000007", b"03DISABLED", b"0010"]
    bx = format_bx_reply(tools)
    assert bx[6] == 3 and len(bx) == 6 + (1 + 42 + 10 + 2 + 2) + 2


def test_formatters_unoccupied_and_status_after_the_word():
    tools = [
        ToolState(2, None, 0x30, 0x2A, unoccupied=True, with_status=True),
        ToolState(3, None, 0x30, 0x2A, unoccupied=True),
        ToolState(4, None, 0x11, 0x2A, disabled=True, with_status=True),
    ]
    payload = format_tx_reply(tools, 0x0080)[:-5]
    assert payload == (
        b"0302UNOCCUPIED000000300000002A\n03UNOCCUPIED\n04DISABLED000000110000002A\n0080"
    )
    bx = format_bx_reply(tools, 0x0080)  # BX: no UNOCCUPIED status byte: disabled (04)
    assert bx[6:-2] == bytes([3, 2, 4, 3, 4, 4, 4]) + struct.pack("<H", 0x0080)


@pytest.fixture
def two(robot):
    """The mock with a second wired tool at a fixed pose (handle 02)."""
    return MockNDITracker(
        robot,
        seed=5,
        frame_rate_hz=1000.0,
        static_tools={0x02: ([100.0, -50.0, 1800.0], [1, 0, 0, 0])},
    )


TX_RECORD = re.compile(
    rb"([0-9A-F]{2})(?:([+-]\d{5}){4}([+-]\d{6}){3}[+-]\d{5}|MISSING|DISABLED|UNOCCUPIED)"
    rb"([0-9A-F]{8})?([0-9A-F]{8})?"
)


def records(reply: bytes) -> list[tuple[int, bytes, int | None]]:
    """(handle, record, port status) of every record of a TX reply, checked by this file's own
    reading of the documented layout."""
    assert ok_crc(reply)
    lines = reply[:-5].split(b"\n")
    assert int(lines[0][:2], 16) == len(lines) - 1 and re.fullmatch(rb"[0-9A-F]{4}", lines[-1])
    out = []
    for rec in [lines[0][2:], *lines[1:-1]]:
        m = TX_RECORD.fullmatch(rec)
        assert m is not None, rec
        out.append((int(m.group(1), 16), rec, None if m.group(4) is None else int(m.group(4), 16)))
    return out


def test_unplugged_tool_is_unoccupied_and_its_handle_is_freed(two):
    for text in ("INIT:", "PINIT:01", "PINIT:02", "PENA:01D", "PENA:02S", "TSTART:"):
        assert ask(two, text)[:4] == b"OKAY", text
    assert [h for h, _, _ in records(ask(two, "TX:0801"))] == [1, 2]
    two.unplug_tool(2)
    (one, empty) = records(ask(two, "TX:0801"))
    assert one[0] == 1 and one[2] == 0x31 and re.match(rb"01[+-]\d{5}", one[1])  # a pose
    assert re.fullmatch(rb"02UNOCCUPIED00000030[0-9A-F]{8}", empty[1]) and empty[2] == 0x30
    two.records_with_status = False
    assert records(ask(two, "TX:0801"))[1][1] == b"02UNOCCUPIED"
    body = ask(two, "BX:0801")[6:-2]
    assert body[0] == 2 and body[1:3] == b"\x01\x01" and body[43:45] == b"\x02\x04"
    assert ask(two, "PHSR:01")[:-5] == b"0102030"  # the emptied handle is to be freed
    assert ask(two, "PHF:02")[:4] == b"OKAY" and 2 not in two.ports
    assert [h for h, _, _ in records(ask(two, "TX:0801"))] == [1]
    two.plug_tool(2)  # back in: to be set up again
    assert ask(two, "PHSR:02")[:-5] == b"0102001"


def test_pdis_makes_a_handle_disabled_while_tracking(two):
    for text in ("INIT:", "PINIT:01", "PINIT:02", "PENA:01D", "PENA:02S", "TSTART:"):
        ask(two, text)
    assert ask(two, "PDIS:02")[:4] == b"OKAY"
    _, disabled = records(ask(two, "TX:0001"))
    assert re.fullmatch(rb"02DISABLED00000011[0-9A-F]{8}", disabled[1])
    two.records_with_status = False
    assert records(ask(two, "TX:0001"))[1][1] == b"02DISABLED"


def test_port_status_fault_bits_and_reply_options(dev):
    tracking(dev)
    dev.port_status_extra = {0x01: 0x1000 | 0x0200}
    assert int(TX_POSE.fullmatch(ask(dev, "TX:0001")).group(10), 16) == 0x1231
    body = ask(dev, "BX:0801")[6:-2]
    assert struct.unpack_from("<I", body, 35)[0] == 0x1231
    for option, code in (("0003", b"ERROR23"), ("1001", b"ERROR23"), ("0800", b"ERROR09")):
        assert ask(dev, f"TX:{option}")[:7] == code, option
    dev.all_transforms = False  # an older tracker without reply option 0x0800
    assert ask(dev, "TX:0801")[:7] == b"ERROR23" and ask(dev, "BX:0801")[:7] == b"ERROR23"
    assert TX_POSE.fullmatch(ask(dev, "TX:0001"))


def test_comm_code_a_is_230400_baud(dev):
    assert ask(dev, "COMM:A0000", baud=9600)[:4] == b"OKAY" and dev.baud == 230400
    assert ask(dev, "INIT:", baud=230400)[:4] == b"OKAY" and dev.framing_errors == 0
    assert ask(dev, "COMM:B0000", baud=230400)[:7] == b"ERROR06"  # no such code


# -- faults --------------------------------------------------------------------------------------
def test_injected_faults(dev):
    tracking(dev)
    good = ask(dev, "TX:0001")
    dev.inject("drop")
    assert ask(dev, "TX:0001", timeout=0.05) == b""
    dev.inject("garble")
    garbled = ask(dev, "TX:0001")
    assert len(garbled) == len(good) and garbled.endswith(b"\r") and not ok_crc(garbled)
    dev.inject("crc")
    bad = ask(dev, "TX:0001")
    assert not ok_crc(bad) and TX_POSE.fullmatch(bad)  # content intact, CRC field wrong
    dev.inject("truncate")
    cut = ask(dev, "TX:0001")
    assert len(cut) == len(good) // 2 and b"\r" not in cut
    assert ok_crc(ask(dev, "TX:0001"))  # one-shot faults are used up
    with pytest.raises(ValueError, match="unknown fault"):
        dev.inject("smoke")


@pytest.mark.parametrize(
    "kind, field, value",
    [
        ("nan", 4 + 0, "nan"),
        ("inf", 4 + 2, "inf"),
        ("nan_quaternion", 1, "nan"),
        ("inf_rms", 7, "inf"),
    ],
)
def test_number_faults_spoil_one_frame_in_crc_valid_replies(robot, kind, field, value):
    """A number fault spoils the next frame measured, in every reply to it: BX carries the
    float32 NaN / inf with valid CRCs; TX's digit fields cannot, so it spells it as printf
    would. The frame after is clean."""
    clock = FakeClock()
    dev = tracking(MockNDITracker(robot, seed=5, frame_rate_hz=1000.0, clock=clock))

    def numbers() -> tuple[float, ...]:  # q0 qx qy qz x y z rms of a BX reply, CRCs checked
        bx = ask(dev, "BX:0001")
        assert crc16(bx[:4]) == struct.unpack_from("<H", bx, 4)[0]
        assert crc16(bx[6:-2]) == struct.unpack("<H", bx[-2:])[0]
        return struct.unpack_from("<8f", bx, 6 + 3)

    assert all(np.isfinite(numbers()))
    dev.inject(kind)
    assert all(np.isfinite(numbers()))  # the same frame as before: measured already
    clock.t += 0.002  # the next frame: the spoiled one
    spoiled = numbers()
    assert str(spoiled[field]) == value
    assert all(np.isfinite(v) for i, v in enumerate(spoiled) if i != field)
    assert numbers() == spoiled or np.isnan(spoiled[field])  # every poll of it (nan != nan)
    tx = ask(dev, "TX:0001")
    assert ok_crc(tx) and re.search(rb"\+ +" + value.encode(), tx) and not TX_POSE.fullmatch(tx)
    clock.t += 0.002
    assert all(np.isfinite(numbers()))
    with pytest.raises(ValueError, match="unknown fault"):
        dev.inject("nan_everything")


def test_nan_rate_from_the_url():
    dev = device_for_url("ndimock://?seed=12&nan=1")
    try:
        assert dev.faults.nan == 1.0
    finally:
        dev.configure(nan=0.0)


def test_faults_touch_only_tracking_replies(dev):
    dev.configure(drop=1.0)
    assert ok_crc(ask(dev, "INIT:"))
    dev.configure(drop=0.0, garble=1.0)
    for text in ("PINIT:01", "PENA:01D", "TSTART:"):
        assert ok_crc(ask(dev, text))
    reply = ask(dev, "BX:0001")
    assert reply[:2] == b"\xc4\xa5" and crc16(reply[6:-2]) != struct.unpack("<H", reply[-2:])[0]
    with pytest.raises(ValueError, match="unknown fault setting"):
        dev.configure(smoke=1.0)


def test_reply_delay_jitter_and_order(dev):
    tracking(dev)
    dev.faults = FaultSettings(delay_s=0.03, jitter_s=0.02)
    t0 = time.monotonic()
    dev.feed(cmd("TX:0001") + cmd("BX:0001"))
    first = dev.read(100_000, 1.0)
    assert 0.03 <= time.monotonic() - t0 < 0.5
    assert TX_POSE.fullmatch(first)  # the TX reply comes before the BX one, whatever the jitter
    assert dev.read(100_000, 1.0)[:2] == b"\xc4\xa5"


def test_discard_input_keeps_what_is_in_flight(dev):
    tracking(dev)
    dev.configure(delay_s=0.05)
    dev.feed(cmd("TX:0001"))
    dev.discard_input()  # the host flushes before the late reply arrives
    assert TX_POSE.fullmatch(dev.read(100_000, 0.5))


# -- URL handler -------------------------------------------------------------------------------------
def test_url_default_device_and_options():
    port = serial.serial_for_url(
        "ndimock://?seed=11&frame_rate=250&delay_ms=2&jitter_ms=1", timeout=0.1
    )
    try:
        dev = device_for_url("ndimock://?seed=11")
        assert dev.frame_rate_hz == 250.0 and dev.faults.delay_s == pytest.approx(0.002)
        port.send_break(0.001)
        assert port.read(10) == b"RESETBE6F\r"
        port.write(cmd("INIT:"))
        assert port.read(100)[:4] == b"OKAY"
    finally:
        port.close()
        dev.configure(delay_s=0, jitter_s=0)


@pytest.mark.parametrize(
    "url, match",
    [
        ("ndimock://?bogus=1", "unknown option 'bogus'"),
        ("ndimock://?drop=x", "not a number"),
        ("ndimock://?drop=-1", "non-negative"),
        ("ndimock://nobody", "register_robot"),
    ],
)
def test_url_errors_are_explicit(url, match):
    with pytest.raises(serial.SerialException, match=match):
        serial.serial_for_url(url)


def test_registered_robot_unplug_and_replug(robot):
    name = f"bench{next(_names)}"
    dev = register_robot(name, robot, frame_rate_hz=500.0)
    try:
        assert get_device(name) is dev
        with pytest.raises(serial.SerialException, match="only"):
            serial.serial_for_url(f"ndimock://{name}?seed=1")
        port = serial.serial_for_url(f"ndimock://{name}", timeout=0.05)
        port.write(cmd("RESET:0"))
        assert port.read(20) == b"RESETBE6F\r"
        dev.unplug()
        with pytest.raises(serial.SerialException, match="disconnected"):
            port.write(cmd("INIT:"))
        with pytest.raises(serial.SerialException, match="unplugged"):
            serial.serial_for_url(f"ndimock://{name}")
        dev.replug()
        with pytest.raises(serial.SerialException):  # the old port stays dead, as a vanished tty
            port.read(1)
        port.close()
        port = serial.serial_for_url(f"ndimock://{name}", timeout=0.05)
        port.write(cmd("RESET:0"))
        assert port.read(20) == b"RESETBE6F\r"
        port.close()
    finally:
        unregister(name)
    with pytest.raises(KeyError, match=name):
        get_device(name)


def test_url_read_honours_timeout(dev):
    name = f"quiet{next(_names)}"
    from hexcal.mock_hw.ndi_registry import register_device

    register_device(name, dev)
    try:
        with serial.serial_for_url(f"ndimock://{name}", timeout=0.05) as port:
            t0 = time.monotonic()
            assert port.read(5) == b""
            assert 0.04 <= time.monotonic() - t0 < 0.5
            assert port.in_waiting == 0
    finally:
        unregister(name)


# -- pty bridge --------------------------------------------------------------------------------------
def test_pty_serves_resets_and_sees_the_host_baud(dev):
    with PtyTracker(dev) as pty:
        path = pty.device_path
        assert os.path.islink(path) and os.readlink(path).startswith("/dev/pts/")
        with serial.Serial(path, 9600, timeout=0.5) as port:
            port.write(cmd("RESET:0"))
            assert port.read_until(b"\r") == b"RESETBE6F\r"
            port.write(cmd("COMM:50000"))
            assert port.read_until(b"\r")[:4] == b"OKAY"
            port.timeout = 0.05
            port.write(cmd("INIT:"))  # still at 9600: the tracker hears noise
            assert port.read(10) == b""
            assert dev.framing_errors == 1
            port.baudrate = 115200
            port.timeout = 0.5
            port.write(cmd("INIT:"))
            assert port.read_until(b"\r")[:4] == b"OKAY"
        thread = pty._thread
    assert not thread.is_alive()
    assert not os.path.exists(path)


def test_pty_unplug_and_replug_keep_the_path(dev):
    with PtyTracker(dev) as pty:
        path = pty.device_path
        port = serial.Serial(path, 9600, timeout=0.2)
        pty.unplug()
        assert not os.path.exists(path) and not pty.plugged
        with pytest.raises(serial.SerialException):
            port.write(b"RESET 0\r")
        port.close()
        pty.replug()
        assert os.path.islink(path) and pty.plugged
        with serial.Serial(path, 9600, timeout=0.5) as port:
            port.write(b"RESET 0\r")
            assert port.read_until(b"\r") == b"RESETBE6F\r"
