"""The NDI tracker contract over a real serial line: a pseudo-terminal pair (os.openpty), the
tracker a responder in another process (tests/ndi_responder.py) written from the NDI Combined
API's documented reply forms with the standard library alone — not hexcal's mock — at two of
the baud rates the rig file allows. The line carries the driver's rate changes (the responder
reads them from the pty and garbles what crosses at mismatched rates), replies come in pieces,
split before their CRC, cut by a tracker that resets half way, or not at all."""

from __future__ import annotations

import contextlib
import json
import os
import select
import subprocess
import sys
import time
import tty
from pathlib import Path

import numpy as np
import pytest

from hexcal.acquire.devices import TrackerConfig
from hexcal.drivers.ndi import NDITracker, TrackerError, TrackerTimeout

RESPONDER = Path(__file__).with_name("ndi_responder.py")
#: The tool's pose as the responder reports it.
POSITION = np.array([123.45, -67.89, -1502.31])
QUATERNION = np.array([0.9239, 0.0, 0.3827, 0.0])
#: Two working rates the rig file allows (TrackerConfig.baudrate) and the NDI API has (COMM).
BAUDS = [115200, 921600]


class Responder:
    """The responder process on a fresh pty pair; ``path`` is the slave's device path."""

    def __init__(self):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.proc = subprocess.Popen(
            [sys.executable, str(RESPONDER), str(self.master), str(self.slave)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            pass_fds=(self.master, self.slave),
        )
        # The child holds both ends now; the test process keeps none, so the line is the
        # child's alone (the driver opens the slave by its path).
        os.close(self.master)
        os.close(self.slave)

    def control(self, **request) -> object:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps(request) + "\n")
        self.proc.stdin.flush()
        ready, _, _ = select.select([self.proc.stdout], [], [], 10.0)
        assert ready, "the responder did not answer its control line"
        return json.loads(self.proc.stdout.readline())["ok"]

    def close(self) -> None:
        with contextlib.suppress(OSError, ValueError):
            assert self.proc.stdin is not None
            self.proc.stdin.close()  # the responder stops when its input closes
        try:
            self.proc.wait(5.0)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5.0)
        if self.proc.stdout is not None:
            self.proc.stdout.close()


@pytest.fixture
def responder():
    r = Responder()
    yield r
    r.close()


def tracker(responder: Responder, baud: int, **kw) -> NDITracker:
    # As the rig file would give it: validated by the rig file's model first.
    cfg = TrackerConfig(url=responder.path, baudrate=baud, reset="command", timeout_s=0.5)
    return NDITracker(cfg.url, cfg.baudrate, cfg.timeout_s, reset=cfg.reset, **kw)


def assert_pose(trk: NDITracker, binary: bool) -> int:
    frame = trk.poll_binary() if binary else trk.poll()
    (tool,) = frame.tools
    assert tool.state == "ok" and tool.handle == 0x0A
    tol = 1e-4 if binary else 0.006  # float32 / TX's 0.01 mm and 1e-4 steps, rounded
    np.testing.assert_allclose(tool.position, POSITION, atol=tol)
    np.testing.assert_allclose(
        tool.quaternion / np.linalg.norm(tool.quaternion),
        QUATERNION / np.linalg.norm(QUATERNION),
        atol=1e-4,
    )
    assert frame.frame_number is not None
    return frame.frame_number


@pytest.mark.parametrize("baud", BAUDS)
def test_contract_over_a_pty_at_the_rig_files_rates(responder, baud):
    with tracker(responder, baud) as trk:
        assert trk.setup_tools() == (0x0A,)
        trk.start()
        frames = []
        for k in range(20):
            frames.append(assert_pose(trk, binary=k % 2 == 1))
            # A tracker numbers its frames at its own rate (60 Hz here); at 921600 baud twenty
            # polls fit inside one frame, so pace them a frame apart to see the count advance.
            time.sleep(1.5 / 60.0)
        assert frames == sorted(frames) and frames[-1] > frames[0]
        sample = trk.sample()
        assert sample.fault is None and sample.position is not None
    served = responder.control(stats=True)
    names = [(name, rate) for name, rate in served["served"]]
    # Reset and COMM at 9600, everything after COMM at the working rate; COMM back to 9600 on
    # close (answered at the working rate, then the tracker switched).
    assert names[0] == ("RESET", 9600) and names[1] == ("COMM", 9600)
    assert all(rate == baud for _, rate in names[2:])
    assert names[-1][0] == "COMM" and served["baud"] == 9600


@pytest.mark.parametrize("baud", BAUDS)
def test_replies_in_pieces_are_read_whole(responder, baud):
    """Every reply written in pieces of 1 to 7 bytes, 1 ms apart: the driver's partial reads
    put them together (ASCII to their CR, BX to the length its header gives)."""
    responder.control(chunks=[1, 7], gap_s=0.001)
    with tracker(responder, baud) as trk:
        trk.setup_tools()
        trk.start()
        for k in range(10):
            assert_pose(trk, binary=k % 2 == 1)


@pytest.mark.parametrize("baud", BAUDS)
def test_a_reply_split_before_its_crc_is_read_whole(responder, baud):
    """Every reply held back 0.2 s (less than the 0.5 s timeout) before its CRC — for BX, inside
    its header: one reply across two reads, well apart."""
    responder.control(split_before_crc_s=0.2)
    with tracker(responder, baud) as trk:
        trk.setup_tools()
        trk.start()
        assert_pose(trk, binary=False)
        assert_pose(trk, binary=True)


@pytest.mark.parametrize("baud", BAUDS)
def test_a_reset_in_the_middle_of_a_reply_is_never_a_frame_and_reconnect_recovers(responder, baud):
    """The tracker resets half way through a TX reply (a power dip): what came is refused, the
    tracker — back at 9600 baud, not initialised — answers nothing at the working rate, and the
    driver says so each time; reconnect() resets it by command, and poses come again."""
    with tracker(responder, baud) as trk:
        trk.setup_tools()
        trk.start()
        assert_pose(trk, binary=False)
        responder.control(reset_mid_reply=True)
        with pytest.raises(TrackerError) as cut:
            trk.poll()
        assert "incomplete reply" in str(cut.value) or "CRC" in str(cut.value), cut.value
        with pytest.raises(TrackerTimeout, match=r"no reply from the tracker on .* to 'TX:0801'"):
            trk.poll()
        trk.reconnect()
        assert trk.tracking
        for k in range(4):
            assert_pose(trk, binary=k % 2 == 1)


@pytest.mark.parametrize("baud", BAUDS)
def test_a_line_that_goes_silent_times_out_within_its_bound_and_recovers(responder, baud):
    with tracker(responder, baud) as trk:
        trk.setup_tools()
        trk.start()
        assert_pose(trk, binary=False)
        responder.control(silent=True)
        for binary in (False, True):
            t0 = time.monotonic()
            with pytest.raises(TrackerTimeout, match=r"no reply from the tracker .* within 0.5 s"):
                trk.poll_binary() if binary else trk.poll()
            assert 0.45 <= time.monotonic() - t0 < 2.0  # the timeout, and not forever
        responder.control(silent=False)
        for k in range(4):
            assert_pose(trk, binary=k % 2 == 1)
