"""The plain-text line protocol: the parser, its errors (naming source and line), and the
LineTracker reader over pyserial's ``loop://`` and over a real pseudo-terminal."""

from __future__ import annotations

import math
import os
import threading
import tty

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hexcal.acquire.acquisition import TrackerSample
from hexcal.drivers.lineproto import (
    MAX_LINE,
    LineProtocolError,
    LineTracker,
    format_missing,
    format_pose,
    parse_line,
    parse_lines,
)
from hexcal.drivers.ndi import TrackerDisconnected, TrackerError, TrackerTimeout
from hexcal.mock_hw.robot import MockRobot
from hexcal.sim.robots import left_hand

SRC = "/dev/ttyLINE"


def test_parse_a_pose_with_and_without_rms():
    rec = parse_line("12.5 0.013 -0.004 200.002 1 0 0 0 0.011\r\n", 3, SRC, received_at=9.0)
    assert rec.t == 12.5 and rec.lineno == 3 and rec.received_at == 9.0 and not rec.missing
    np.testing.assert_allclose(rec.position, [0.013, -0.004, 200.002])
    np.testing.assert_allclose(rec.quaternion, [1, 0, 0, 0])
    assert rec.rms_mm == 0.011
    rec = parse_line(b"1\t2 3 4   0.99995 0.01 0 0  # trailing comment")
    assert math.isnan(rec.rms_mm)
    assert np.linalg.norm(rec.quaternion) == pytest.approx(1.0)  # renormalised
    assert rec.quaternion[1] == pytest.approx(0.01, rel=1e-3)


def test_comments_blanks_and_missing():
    assert parse_line("# header") is None
    assert parse_line("   \n") is None
    rec = parse_line("MISSING 14.25")
    assert rec.missing and rec.t == 14.25 and rec.quaternion is None


@pytest.mark.parametrize(
    "line, match",
    [
        (
            "1 2 3 4 1 0 0",
            r"line 7 from /dev/ttyLINE: expected 't x y z qw qx qy qz \[rms\]' .* got 7 fields",
        ),
        ("1 2 3 4 1 0 0 0 0.1 5", "got 10 fields"),
        ("1 2 x 4 1 0 0 0", r"y = 'x' is not a finite number"),
        ("1 2 3 nan 1 0 0 0", "z = 'nan' is not a finite number"),
        ("1 2 3 4 0 0 0 0.5", "norm 0.500000, not 1"),
        ("1 2 3 4 1 0 0 0 -0.1", "rms = -0.1 is negative"),
        ("MISSING", "exactly one field"),
        ("MISSING 1 2", "exactly one field"),
        (b"1 2 3 \xff 1 0 0 0", "not ASCII"),
    ],
)
def test_errors_name_source_and_line(line, match):
    with pytest.raises(LineProtocolError, match=match) as err:
        parse_line(line, 7, SRC)
    assert err.value.lineno == 7 and SRC in str(err.value)
    assert isinstance(err.value, ValueError) and isinstance(err.value, TrackerError)


def test_parse_lines_numbers_from_one():
    text = ["# rig 2", "0 0 0 0 1 0 0 0", "", "MISSING 1", "2 1 1 1 1 0 0 x"]
    recs = parse_lines(text, "log.txt")
    assert next(recs).lineno == 2
    assert next(recs).missing
    with pytest.raises(LineProtocolError, match=r"line 5 from log\.txt"):
        next(recs)


def test_format_round_trip():
    q = Rotation.from_euler("xyz", [1, 2, 3], degrees=True).as_quat(scalar_first=True)
    p = np.array([12.3456789, -0.000123, 1999.9999])
    rec = parse_line(format_pose(7.25, p, q, 0.0123))
    np.testing.assert_allclose(rec.position, p, rtol=1e-8)
    np.testing.assert_allclose(rec.quaternion, q, atol=1e-8)
    assert rec.rms_mm == 0.0123 and parse_line(format_missing(3)).missing


def test_line_tracker_over_loop():
    robot = MockRobot(left_hand(), seed=2)
    with LineTracker("loop://", timeout=0.1) as trk:
        sent = [robot.tracker_sample() for _ in range(3)]
        stream = "# mock stream\n" + "".join(format_pose(i * 0.01, *s) for i, s in enumerate(sent))
        trk.port.write((stream + format_missing(0.03)).encode())
        for s in sent:
            rec = trk.read_pose()
            np.testing.assert_allclose(rec.position, s[0], rtol=1e-8)
            np.testing.assert_allclose(rec.quaternion, s[1], atol=1e-8)
        missing = trk.sample()
        assert isinstance(missing, TrackerSample) and missing.position is None
        assert (
            "MISSING" in missing.fault and "loop://" in missing.fault and "line 5" in missing.fault
        )
        trk.port.write(b"1 2 3 4 1 0 0 0\n")
        s = trk.sample()
        assert s.fault is None and s.t > 0
        trk.port.write(b"1 2 3")  # an unfinished line
        with pytest.raises(
            TrackerTimeout, match=r"no complete line .* loop://.*unfinished line"
        ) as err:
            trk.read_pose()
        assert err.value.partial == b"1 2 3"
        trk.port.write(b" 4 1 0 0 0 oops\n")
        with pytest.raises(LineProtocolError, match="line 7 from loop://"):
            trk.read_pose()
        trk.port.write(b"x" * (MAX_LINE + 10))
        with pytest.raises(LineProtocolError, match="without a newline"):
            trk.read_pose()


def test_line_tracker_over_a_pty_and_unplug():
    master, slave = os.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    trk = LineTracker(path, timeout=0.5).open()
    try:
        writer = threading.Thread(
            target=os.write, args=(master, b"0.5 1 2 3 1 0 0 0 0.01\n"), daemon=True
        )
        writer.start()
        rec = trk.read_pose()
        writer.join()
        assert rec.t == 0.5 and rec.rms_mm == 0.01
        os.close(master)
        os.close(slave)
        master = -1
        with pytest.raises(
            TrackerDisconnected, match=f"lost the connection to the tracker on {path}"
        ):
            trk.read_pose()
        assert trk.port is None
        with pytest.raises(TrackerDisconnected, match="not open"):
            trk.read_pose()
    finally:
        trk.close()
        if master >= 0:
            os.close(master)
            os.close(slave)


def test_line_tracker_bad_port():
    with pytest.raises(
        TrackerDisconnected, match="cannot open the tracker port /nonexistent/ttyLINE"
    ):
        LineTracker("/nonexistent/ttyLINE").open()


@pytest.mark.parametrize("bad", [math.inf, math.nan, 0.0, -1.0, 61.0])
def test_line_tracker_timeout_is_bounded(bad):
    with pytest.raises(ValueError, match=r"^timeout must be a finite number of seconds"):
        LineTracker("loop://", timeout=bad)
