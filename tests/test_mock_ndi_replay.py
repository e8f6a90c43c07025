"""Replaying captured tracker traffic: record a session with pyserial's ``spy://`` handler on the
mock tracker's pseudo-terminal, then run the driver against ``ndireplay://`` with no tracker.

The capture format is spy's own (``FormatHexdump``): the parser is checked against that
formatter, not against hand-copied lines only, so the two cannot drift apart unnoticed.
"""

from __future__ import annotations

import io
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import serial
from serial.urlhandler.protocol_spy import FormatHexdump

import hexcal.mock_hw  # noqa: F401  (registers ndimock:// and ndireplay://)
from hexcal.drivers.ndi import NDITracker, TrackerDisconnected, TrackerFrame
from hexcal.mock_hw.ndi_tracker import MockNDITracker
from hexcal.mock_hw.protocol_ndireplay import CaptureError, ReplayDivergence, parse_capture
from hexcal.mock_hw.pty_tracker import PtyTracker
from hexcal.mock_hw.robot import MockRobot
from hexcal.sim.robots import left_hand
from hexcal.sim.simulate import NoiseModel

# Short waits keep the tests fast; a pty carries no BREAK, so the RESET command resets.
FAST = dict(timeout=0.25, settle_s=0.0, resync_s=0.02, reset_timeout_s=0.2, reset="command")


def run_session(trk: NDITracker) -> list[TrackerFrame]:
    """The recorded sequence: connect (reset, COMM, INIT, VER, tools, TSTART), text and binary
    polls, close (TSTOP, COMM back to 9600)."""
    trk.connect()
    try:
        return [trk.poll(), trk.poll_binary(), trk.poll(), trk.poll_binary(), trk.poll()]
    finally:
        trk.close()


def spy_lines(*records: tuple[str, bytes], color: bool = False) -> str:
    """What spy writes for ``records`` ((direction, bytes) or ("BRK", text)), by spy's own
    formatter."""
    out = io.StringIO()
    fmt = FormatHexdump(out, color)
    for direction, data in records:
        if direction == "TX":
            fmt.tx(data)
        elif direction == "RX":
            fmt.rx(data)
        else:
            fmt.control(direction, data.decode())
    return out.getvalue()


def label(line: str) -> str:
    return line[11:15].strip()  # spy: 10-character timestamp, space, label padded to 4


def first_line(lines: list[str], direction: str, ascii_start: str) -> int:
    """1-based number of the first ``direction`` row whose ASCII column starts with
    ``ascii_start`` (the test finds lines by what a person reads, independently of the parser)."""
    for n, line in enumerate(lines, start=1):
        if label(line) == direction and line[72:].startswith(ascii_start):
            return n
    raise AssertionError(f"no {direction} row showing {ascii_start!r}")


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> tuple[Path, list[TrackerFrame], MockNDITracker]:
    """A live session through spy on the pty: (capture file, frames decoded, the mock)."""
    robot = MockRobot(left_hand(), noise=NoiseModel(0.01, 0.002, 0.0), seed=21)
    device = MockNDITracker(robot, seed=21, frame_rate_hz=1000.0)  # a new frame at every poll
    path = tmp_path_factory.mktemp("capture") / "cap.txt"
    with PtyTracker(device) as pty:
        trk = NDITracker(f"spy://{pty.device_path}?file={path}", **FAST)
        spy_files: list[io.TextIOBase] = []
        real_open = trk.open

        def open_and_note_spy_file() -> NDITracker:
            out = real_open()
            spy_files.append(trk.port.formatter.output)
            return out

        trk.open = open_and_note_spy_file  # type: ignore[method-assign]
        try:
            frames = run_session(trk)
        finally:
            for f in spy_files:  # spy never closes its capture file itself
                f.close()
    return path, frames, device


def assert_same_frames(replayed: list[TrackerFrame], live: list[TrackerFrame]) -> None:
    assert len(replayed) == len(live)
    for r, v in zip(replayed, live, strict=True):
        assert r.frame_number == v.frame_number
        assert r.system_status == v.system_status
        assert [(t.handle, t.state, t.port_status) for t in r.tools] == [
            (t.handle, t.state, t.port_status) for t in v.tools
        ]
        for rt, vt in zip(r.tools, v.tools, strict=True):
            np.testing.assert_array_equal(rt.position, vt.position)  # mm, bit for bit
            np.testing.assert_array_equal(rt.quaternion, vt.quaternion)
            assert rt.rms_mm == vt.rms_mm


# ------------------------------------------------------------------------------------------------
# (a) record live, replay, same frames
# ------------------------------------------------------------------------------------------------
def test_replay_decodes_the_live_frames(recorded):
    path, live, device = recorded
    # The live session really ran: new frames with noisy poses, binary and text.
    numbers = [f.frame_number for f in live]
    assert numbers == sorted(numbers) and len(set(numbers)) == len(numbers)
    assert len({tuple(f.tool(1).position) for f in live}) == len(live)
    assert device.framing_errors == 0 and device.baud == 9600  # COMM both ways reached the pty

    for _ in range(2):  # every open replays from the capture's start
        trk = NDITracker(f"ndireplay://{path}", **FAST)
        trk.connect()
        port = trk.port
        frames = [trk.poll(), trk.poll_binary(), trk.poll(), trk.poll_binary(), trk.poll()]
        trk.close()
        assert_same_frames(frames, live)
        assert all(f.port == f"ndireplay://{path}" for f in frames)
        assert port.tx_remaining == 0 and port.rx_remaining == 0  # the whole capture, no more


def test_spy_records_no_baud_change_so_replay_checks_comm_bytes(recorded):
    """spy logs COMM's bytes but not the port's baud switch that follows; the replay accepts any
    rate change and catches a different working rate by COMM's bytes."""
    path, _, device = recorded
    text = path.read_text()
    assert "COMM:50000" in text and "115200" not in text
    assert any(c.startswith("COMM:50000") for c in device.commands)
    lines = text.split("\n")
    trk = NDITracker(f"ndireplay://{path}", baudrate=57600, **FAST)
    with pytest.raises(TrackerDisconnected) as err:
        trk.open()
    msg = str(err.value)
    line = first_line(lines, "TX", "COMM:5")
    assert f"diverged from the capture at line {line} of {path}" in msg
    assert "expects the driver to send b'COMM:500000048\\r'" in msg
    assert "the driver sent b'COMM:40000" in msg
    assert trk.port is None  # the driver closed the half-open port


# ------------------------------------------------------------------------------------------------
# (b) divergence
# ------------------------------------------------------------------------------------------------
def test_a_different_command_sequence_diverges_at_its_line(recorded):
    path, _, _ = recorded
    lines = path.read_text().split("\n")
    trk = NDITracker(f"ndireplay://{path}", **FAST)
    trk.connect()
    with pytest.raises(TrackerDisconnected) as err:
        trk.poll_binary()  # the capture's first poll is TX, not BX
    msg = str(err.value)
    line = first_line(lines, "TX", "TX:0801")  # reply option 0x0800 (out-of-volume poses)
    assert f"the driver's traffic diverged from the capture at line {line} of {path}" in msg
    assert "expects the driver to send b'TX:0801C19B\\r'" in msg
    assert "the driver sent b'BX:080100EC\\r'" in msg
    trk.close()


def test_divergence_consumes_nothing_and_writes_may_be_split(tmp_path):
    path = tmp_path / "cap.txt"
    path.write_text(spy_lines(("TX", b"PING\r"), ("RX", b"PONG\r"), ("TX", b"BYE\r")))
    port = serial.serial_for_url(f"ndireplay://{path}", timeout=0.01)
    with pytest.raises(ReplayDivergence, match=r"diverged from the capture at line 1 of .*"):
        port.write(b"PONX\r")
    assert port.tx_remaining == 9  # nothing of the failed write was taken
    assert port.write(b"PI") == 2 and port.in_waiting == 0  # half a command: no reply yet
    assert port.write(b"NG\rBY") == 5  # on past the reply: it is due, unread
    assert port.read(100) == b"PONG\r"
    port.write(b"E\r")
    assert port.tx_remaining == 0 and port.rx_remaining == 0
    port.close()


# ------------------------------------------------------------------------------------------------
# (c) malformed capture, missing capture
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "edit, reason",
    [
        (lambda ls, i: ls.__setitem__(i, ls[i].replace("0000  52 45", "0000  52 4G", 1)), "hex"),
        (lambda ls, i: ls.__setitem__(i, "garbage written over the capture"), "timestamp"),
        (lambda ls, i: ls.__setitem__(i, ls[i][:16]), "no hex row offset"),
        (lambda ls, i: ls.__setitem__(i, ls[i].replace("TX  ", "XT  ", 1)), "unknown label"),
    ],
)
def test_malformed_line_names_file_and_line(recorded, tmp_path, edit: Callable, reason: str):
    path, _, _ = recorded
    lines = path.read_text().split("\n")
    bad_line = first_line(lines, "TX", "RESET:0")
    edit(lines, bad_line - 1)
    bad = tmp_path / "bad.txt"
    bad.write_text("\n".join(lines))
    with pytest.raises(CaptureError) as err:
        serial.serial_for_url(f"ndireplay://{bad}")
    assert f"capture {bad}, line {bad_line}:" in str(err.value) and reason in str(err.value)
    with pytest.raises(TrackerDisconnected, match=f"capture {bad}, line {bad_line}:"):
        NDITracker(f"ndireplay://{bad}", **FAST).open()


def test_deleted_row_inside_a_reply_is_malformed(recorded, tmp_path):
    path, _, _ = recorded
    lines = path.read_text().split("\n")
    # A TX reply runs over several 16-byte rows: drop its second row (offset 0010).
    second = next(
        n
        for n, line in enumerate(lines, start=1)
        if label(line) == "RX" and line[16:22] == "0010  "
    )
    del lines[second - 1]
    bad = tmp_path / "bad.txt"
    bad.write_text("\n".join(lines))
    with pytest.raises(CaptureError, match=f"line {second}: row offset 0020 does not continue"):
        serial.serial_for_url(f"ndireplay://{bad}")


def test_missing_capture_names_the_path(tmp_path):
    missing = tmp_path / "nowhere" / "cap.txt"
    with pytest.raises(serial.SerialException, match=f"cannot read the capture '{missing}'"):
        serial.serial_for_url(f"ndireplay://{missing}")
    with pytest.raises(serial.SerialException, match="takes no options"):
        serial.serial_for_url(f"ndireplay://{missing}?file=x")


# ------------------------------------------------------------------------------------------------
# (d) capture exhausted
# ------------------------------------------------------------------------------------------------
def test_driver_sending_past_the_end_of_the_capture(recorded, tmp_path):
    path, live, _ = recorded
    lines = path.read_text().split("\n")
    cut = first_line(lines, "TX", "BX:0801")  # keep the session up to the first TX reply
    short = tmp_path / "short.txt"
    short.write_text("\n".join(lines[: cut - 1]) + "\n")
    last = max(n for n, line in enumerate(lines[: cut - 1], 1) if label(line) in ("TX", "RX"))
    trk = NDITracker(f"ndireplay://{short}", **FAST)
    trk.connect()
    assert_same_frames([trk.poll()], live[:1])
    with pytest.raises(TrackerDisconnected) as err:
        trk.poll_binary()
    assert f"capture {short} ends at line {last}; the driver sent more: b'BX:080100EC\\r'" in str(
        err.value
    )
    trk.close()


# ------------------------------------------------------------------------------------------------
# Port semantics
# ------------------------------------------------------------------------------------------------
def test_no_reply_before_its_command_is_sent(tmp_path):
    path = tmp_path / "cap.txt"
    path.write_text(
        spy_lines(("BRK", b"send_break 0.25s"), ("TX", b"VER:4A6EF\r"), ("RX", b"v1\r"))
    )
    port = serial.serial_for_url(f"ndireplay://{path}", timeout=0.05)
    port.reset_input_buffer()
    port.baudrate = 115200  # no line: accepted
    assert port.in_waiting == 0
    t0 = time.monotonic()
    assert port.read(3) == b""  # as a real port with no reply: waits for the timeout
    assert time.monotonic() - t0 >= 0.045
    port.write(b"VER:4A6EF\r")
    assert port.in_waiting == 3
    t0 = time.monotonic()
    assert port.read(2) == b"v1" and port.in_waiting == 1
    assert port.read(5) == b"\r"  # what there is, after the timeout
    assert time.monotonic() - t0 >= 0.045
    with pytest.raises(ReplayDivergence, match=r"ends at line 3; the driver sent more: b'X'"):
        port.write(b"X")
    port.close()
    with pytest.raises(serial.PortNotOpenError):
        port.read(1)


# ------------------------------------------------------------------------------------------------
# (e) the parser reads the hex columns, never the ASCII column
# ------------------------------------------------------------------------------------------------
def test_parser_ignores_an_ascii_column_that_looks_like_hex():
    # Hand-written, as if edited: the ASCII column contradicts the hex and looks like hex.
    row = "01 02 03 " + " " * 40  # 3 bytes, padded to the 49-column hex field
    text = f"000001.000 RX   0000  {row} DE AD BE EF 00 11\n"
    chunks = parse_capture(text, "synthetic")
    assert [(c.direction, c.data) for c in chunks] == [("RX", b"\x01\x02\x03")]
    assert chunks[0].rows == ((0, 1),)
    # Text whose ASCII rendering is hex: "0A 0D C4 A5" shown as such in the ASCII column.
    hexlike = b"0A 0D C4 A5 31"
    text = spy_lines(("TX", hexlike), ("RX", hexlike * 3))
    assert "0A 0D C4 A5" in text.split("\n")[0][72:]
    chunks = parse_capture(text)
    assert [(c.direction, c.data) for c in chunks] == [("TX", hexlike), ("RX", hexlike * 3)]


@pytest.mark.parametrize("color", [False, True])
def test_parser_round_trips_spy_output_of_every_row_length(color: bool):
    rng = np.random.default_rng(3)
    records = []
    for n in (1, 7, 8, 9, 15, 16, 17, 24, 33, 40):  # around the gap after 8 and the row of 16
        records.append(("TX", bytes(rng.integers(0, 256, n, dtype=np.uint8))))
        records.append(("Q-RX", b"reset_input_buffer"))
        records.append(("RX", bytes(rng.integers(32, 127, n, dtype=np.uint8))))  # printable
        records.append(("RX", b"\r\n"))  # a second read: merged with the first
    chunks = parse_capture(spy_lines(*records, color=color))
    expected = []
    for i in range(0, len(records), 4):
        expected += [("TX", records[i][1]), ("RX", records[i + 2][1] + b"\r\n")]
    assert [(c.direction, c.data) for c in chunks] == expected
    # Each row points back at its line: 40 bytes take rows at lines n, n+1, n+2.
    last_tx = chunks[-2]
    assert [start for start, _ in last_tx.rows] == [0, 16, 32]
    assert last_tx.line_at(20) == last_tx.rows[1][1] == last_tx.rows[0][1] + 1
