"""Fuzzing every device parser (hypothesis; marked ``fuzz``: 200 examples per test by default,
10,000 with ``HEXCAL_FUZZ=1``, see conftest.py).

The property, parser by parser: whatever the input, the parser either returns a valid result
whose numbers are all finite, or raises its own documented error type — never another
exception (no ValueError, IndexError, struct.error, OverflowError or RecursionError escaping).

Inputs are arbitrary bytes and text, and near-valid inputs built from valid replies, frames
and files with mutations (flipped bytes, NaN / inf text, truncation, huge numbers) whose CRC is
recomputed afterwards, so that the mutation reaches the field parsers instead of stopping at the
checksum.
"""

from __future__ import annotations

import functools
import io
import json
import math
import string
import struct

import can
import numpy as np
import pytest
import serial
from hypothesis import example, given
from hypothesis import strategies as st
from serial.urlhandler.protocol_spy import FormatHexdump

from hexcal.acquire.acquisition import TrackerSample, checked_tracker_sample
from hexcal.drivers.can_config import (
    CanBusConfig,
    CanConfigError,
    LegEncoderConfig,
    default_can_config,
    load_can_config,
)
from hexcal.drivers.can_encoders import (
    EncoderError,
    LegEncoders,
    TpdoDecoder,
    decode_tpdo,
    describe_error_frame,
)
from hexcal.drivers.crc import check, crc16, crc16_hex
from hexcal.drivers.lineproto import LinePose, LineProtocolError, LineTracker, parse_line
from hexcal.drivers.ndi import (
    BX_START,
    MAX_POSITION_MM,
    NDITracker,
    TrackerError,
    TrackerFrame,
    checked_payload,
    parse_bx_reply,
    parse_phsr_reply,
    parse_tx_reply,
)
from hexcal.mock_hw.ndi_tracker import MockNDITracker
from hexcal.mock_hw.protocol_ndireplay import (
    CaptureChunk,
    CaptureError,
    capture_path,
    parse_capture,
    parse_hex_row,
)
from hexcal.mock_hw.robot import MockRobot
from hexcal.sim.robots import left_hand

pytestmark = pytest.mark.fuzz

PORT = "/dev/ttyFUZZ"

# Text that breaks numbers: what a glitching firmware, a wrong locale or line noise may send.
BAD_NUMBERS = [
    "nan", "NaN", "-nan", "inf", "-inf", "Infinity", "1e999", "-1e999", "1e-999", "0x1F",
    "1_000", "+-1", "--1", "1..2", "9" * 40, "+99999999", "-000000", "١٢٣", " ", "", "\x00",
    "\n", "\r", "+", "-",
]  # fmt: skip


# ------------------------------------------------------------------------------------------------
# What a valid result is
# ------------------------------------------------------------------------------------------------
def assert_valid_frame(frame: TrackerFrame) -> None:
    """Every number in a parsed frame is finite and in its field's range; every usable pose is
    one (finite, unit quaternion, a position a tracker can report); its sample passes the
    acquisition's own check unchanged."""
    assert isinstance(frame, TrackerFrame)
    assert 0 <= frame.system_status <= 0xFFFF
    for tool in frame.tools:
        assert 0 <= tool.handle <= 0xFF and 0 <= tool.port_status < 2**32
        assert tool.frame_number is None or 0 <= tool.frame_number < 2**32
        if tool.state == "ok":
            assert tool.position.shape == (3,) and tool.quaternion.shape == (4,)
            assert np.all(np.isfinite(tool.position)) and np.all(np.isfinite(tool.quaternion))
            assert np.all(np.abs(tool.position) <= MAX_POSITION_MM)
            assert abs(np.linalg.norm(tool.quaternion) - 1.0) < 1e-9
            assert math.isfinite(tool.rms_mm)
        else:
            assert tool.state in ("missing", "disabled", "invalid")
            assert tool.position is None and tool.quaternion is None
            assert tool.problem(PORT)
    for handle in [None, *(t.handle for t in frame.tools)]:
        sample = frame.to_sample(handle)
        assert isinstance(sample, TrackerSample)
        assert (sample.position is None) == (sample.quaternion is None)
        assert sample.position is not None or sample.fault
        assert checked_tracker_sample(sample) is sample


def assert_valid_line_pose(rec: LinePose | None) -> None:
    if rec is None:
        return
    assert math.isfinite(rec.t)
    if rec.position is None:
        assert rec.quaternion is None
        return
    assert np.all(np.isfinite(rec.position)) and np.all(np.isfinite(rec.quaternion))
    assert abs(np.linalg.norm(rec.quaternion) - 1.0) < 1e-9
    assert math.isnan(rec.rms_mm) or (math.isfinite(rec.rms_mm) and rec.rms_mm >= 0)


# ------------------------------------------------------------------------------------------------
# Mutations
# ------------------------------------------------------------------------------------------------
@st.composite
def mutated(draw, data: bytes, text: bool) -> bytes:
    """``data`` with a few mutations: bytes flipped or replaced, spans deleted or duplicated,
    cut short, or a bad number (NaN, inf, huge, malformed) written over or into it."""
    out = bytearray(data)
    for _ in range(draw(st.integers(0, 4))):
        kind = draw(st.sampled_from(["flip", "byte", "delete", "dup", "cut", "number", "insert"]))
        i = draw(st.integers(0, max(len(out) - 1, 0)))
        if kind == "flip" and out:
            out[i] ^= 1 << draw(st.integers(0, 7))
        elif kind == "byte" and out:
            out[i] = draw(st.sampled_from(b"+-0159AF\n\r :.") if text else st.integers(0, 255))
        elif kind == "delete":
            del out[i : i + draw(st.integers(1, 8))]
        elif kind == "dup":
            out[i:i] = out[i : i + draw(st.integers(1, 70))]
        elif kind == "cut":
            del out[i:]
        else:
            bad = draw(st.sampled_from(BAD_NUMBERS)).encode()
            if kind == "number":
                out[i : i + len(bad)] = bad  # over a field, same width when it fits
            else:
                out[i:i] = bad
    return bytes(out)


def with_ascii_crc(payload: bytes) -> bytes:
    return payload + crc16_hex(payload) + b"\r"


def bx_reply(body: bytes) -> bytes:
    """A BX reply around ``body``, both CRCs right (the length field wraps as a uint16 does)."""
    header = BX_START + struct.pack("<H", len(body) & 0xFFFF)
    return header + struct.pack("<H", crc16(header)) + body + struct.pack("<H", crc16(body))


# ------------------------------------------------------------------------------------------------
# Valid replies to start from
# ------------------------------------------------------------------------------------------------
unit_quaternion = (
    st.tuples(*[st.floats(-1, 1)] * 4)
    .filter(lambda q: sum(c * c for c in q) > 0.01)
    .map(lambda q: tuple(c / math.sqrt(sum(v * v for v in q)) for c in q))
)
uint32 = st.integers(0, 2**32 - 1)


def _signed(value: int, digits: int) -> str:
    return ("+" if value >= 0 else "-") + str(abs(value)).zfill(digits)


@st.composite
def tx_payloads(draw) -> bytes:
    """A TX:0001 payload as the documented format writes it (CRC not included)."""
    records = []
    for _ in range(draw(st.integers(0, 3))):
        handle = f"{draw(st.integers(0, 255)):02X}"
        kind = draw(st.sampled_from(["pose", "pose", "missing", "disabled", "unoccupied"]))
        status, frame = f"{draw(uint32):08X}", f"{draw(uint32):08X}"
        if kind == "pose":
            q = draw(unit_quaternion)
            pos = draw(st.lists(st.integers(-999_999, 999_999), min_size=3, max_size=3))
            rms = draw(st.integers(-99_999, 99_999))
            records.append(
                handle
                + "".join(_signed(round(c * 1e4), 5) for c in q)
                + "".join(_signed(p, 6) for p in pos)
                + _signed(rms, 5)
                + status
                + frame
            )
        elif kind == "missing":
            records.append(f"{handle}MISSING{status}{frame}")
        elif kind == "disabled":
            records.append(f"{handle}DISABLED" + draw(st.sampled_from(["", status + frame])))
        else:
            records.append(f"{handle}UNOCCUPIED")
    payload = f"{len(records):02X}" + "".join(r + "\n" for r in records)
    return (payload + f"{draw(st.integers(0, 0xFFFF)):04X}").encode("ascii")


# float32 values: every special (NaN, inf, subnormal, huge), or raw bit patterns (NaN payloads).
float32 = st.one_of(
    st.floats(width=32),
    st.binary(min_size=4, max_size=4).map(lambda b: struct.unpack("<f", b)[0]),
)


@st.composite
def bx_bodies(draw) -> bytes:
    """A BX:0001 body as documented, its numbers anything a float32 can hold."""
    body = bytearray()
    n = draw(st.integers(0, 3))
    body.append(n)
    for _ in range(n):
        handle = draw(st.integers(0, 255))
        state = draw(st.sampled_from([0x01, 0x01, 0x02, 0x04]) | st.integers(0, 255))
        body += bytes([handle, state])
        if state == 0x01:
            if draw(st.booleans()):  # a plausible pose
                q = draw(unit_quaternion)
                p = draw(st.tuples(*[st.floats(-3000, 3000)] * 3))
                numbers = (*q, *p, draw(st.floats(0, 1)))
            else:
                numbers = draw(st.tuples(*[float32] * 8))
            body += struct.pack("<8f", *numbers)
        if state in (0x01, 0x02):
            body += struct.pack("<II", draw(uint32), draw(uint32))
    body += struct.pack("<H", draw(st.integers(0, 0xFFFF)))
    return bytes(body)


# ------------------------------------------------------------------------------------------------
# NDI reply parsers
# ------------------------------------------------------------------------------------------------
def _parse_all(raw: bytes) -> None:
    """Every NDI reply parser on ``raw``: a valid result or a TrackerError."""
    for parse in (parse_tx_reply, parse_bx_reply):
        try:
            frame = parse(raw, 1.0, port=PORT)
        except TrackerError as exc:
            assert exc.port == PORT and str(exc)
        else:
            assert_valid_frame(frame)
    try:
        payload = checked_payload(raw, PORT, "VER:4")
    except TrackerError:
        return
    assert isinstance(payload, bytes)
    try:
        pairs = parse_phsr_reply(payload, PORT, "PHSR:00")
    except TrackerError:
        return
    assert all(0 <= h <= 0xFF and 0 <= s <= 0xFFF for h, s in pairs)


@given(st.binary(max_size=400))
@example(b"")
@example(b"\r")
@example(b"ERROR" + crc16_hex(b"ERROR") + b"\r")
@example(b"ERRORZZ" + crc16_hex(b"ERRORZZ") + b"\r")
@example(BX_START)
@example(BX_START + b"\xff\xff")
def test_ndi_parsers_on_arbitrary_bytes(raw):
    _parse_all(raw)


@given(st.data())
def test_ndi_parsers_on_mutated_tx_replies_with_their_crc_recomputed(data):
    payload = data.draw(tx_payloads())
    if data.draw(st.booleans()):
        payload = data.draw(mutated(payload, text=True))
    raw = with_ascii_crc(payload)
    _parse_all(raw)
    _parse_all(data.draw(mutated(raw, text=True)))  # and with the CRC no longer matching


@given(st.data())
def test_ndi_parsers_on_mutated_bx_replies_with_their_crcs_recomputed(data):
    body = data.draw(bx_bodies())
    if data.draw(st.booleans()):
        body = data.draw(mutated(body, text=False))
    raw = bx_reply(body)
    _parse_all(raw)
    _parse_all(data.draw(mutated(raw, text=False)))  # header, lengths and CRCs hit too


@pytest.mark.parametrize(
    "numbers",
    [
        (1, 0, 0, 0, math.nan, 2, 3, 0.01),
        (1, 0, 0, 0, 1, 2, math.inf, 0.01),
        (math.nan, 0, 0, 0, 1, 2, 3, 0.01),
        (1, 0, 0, 0, 1, 2, 3, -math.inf),
        (1, 0, 0, 0, 3e38, 2, 3, 0.01),
        (1e-45, 0, 0, 0, 1, 2, 3, 0.01),  # a subnormal: no rotation
    ],
)
def test_ndi_bx_frames_with_non_finite_or_absurd_numbers(numbers):
    """The frames the attack campaign found (CRC valid, NaN / inf in a pose), as fixed cases."""
    body = bytes([1, 1, 1]) + struct.pack("<8f", *numbers) + struct.pack("<IIH", 0, 7, 0)
    _parse_all(bx_reply(body))


# ------------------------------------------------------------------------------------------------
# The NDI driver's own read path (a port that answers anything)
# ------------------------------------------------------------------------------------------------
class _FakePort:
    """Just enough of a pyserial port: every command is answered with ``reply``."""

    def __init__(self, reply: bytes):
        self.reply = reply
        self.buf = bytearray()
        self.baudrate = 115200

    @property
    def in_waiting(self) -> int:
        return len(self.buf)

    def reset_input_buffer(self) -> None:
        self.buf.clear()

    def write(self, data: bytes) -> int:
        self.buf += self.reply
        return len(data)

    def read(self, size: int = 1) -> bytes:
        out = bytes(self.buf[:size])
        del self.buf[:size]
        return out


def _fast_tracker(reply: bytes) -> NDITracker:
    # A 1 ms timeout: a reply without its end costs 1 ms, not 1 s.
    trk = NDITracker(PORT, timeout=0.001, resync_s=0.0)
    trk.port = _FakePort(reply)  # type: ignore[assignment]
    return trk


@given(st.data())
def test_ndi_driver_polls_whatever_comes_back(data):
    """The driver's reading of a reply (to its CR, or by the BX header's length) and its frame
    clock, fed frame numbers anything: a frame or a TrackerError, never anything else."""
    source = data.draw(st.sampled_from(["bytes", "tx", "bx"]))
    if source == "bytes":
        replies = [data.draw(st.binary(max_size=200))]
    elif source == "tx":
        replies = [with_ascii_crc(data.draw(tx_payloads())) for _ in range(3)]
    else:
        replies = [bx_reply(data.draw(bx_bodies())) for _ in range(3)]
    replies = [
        data.draw(mutated(r, text=source == "tx")) if data.draw(st.booleans()) else r
        for r in replies
    ]
    trk = _fast_tracker(b"")
    for reply in replies:
        trk.port.reply = reply  # type: ignore[union-attr]
        for poll in (trk.poll, trk.poll_binary):
            try:
                frame = poll()
            except TrackerError:
                continue
            assert_valid_frame(frame)
            assert math.isfinite(frame.received_at)
            assert math.isnan(frame.measured_at) or math.isfinite(frame.measured_at)
    stats = trk.clock_stats()
    assert stats["state"] in ("warming up", "locked", "inconsistent")


# ------------------------------------------------------------------------------------------------
# The line protocol
# ------------------------------------------------------------------------------------------------
def _parse_line_both(line: str | bytes) -> None:
    try:
        rec = parse_line(line, 7, "fuzz")
    except LineProtocolError as exc:
        assert exc.lineno == 7 and "fuzz" in str(exc)
    else:
        assert_valid_line_pose(rec)


number_text = st.one_of(
    st.floats().map(repr),
    st.floats(-1e4, 1e4).map(lambda v: f"{v:.6f}"),
    st.integers(-(10**30), 10**30).map(str),
    st.sampled_from(BAD_NUMBERS),
)


@given(st.one_of(st.text(max_size=200), st.binary(max_size=200)))
@example("1 2 3 4 1 0 0 0 nan")
@example("MISSING inf")
@example(b"1 2 3 4 1 0 0 0\xff")
def test_line_protocol_on_arbitrary_text(line):
    _parse_line_both(line)


@given(
    st.lists(number_text, min_size=1, max_size=10),
    st.sampled_from([" ", "\t", "  "]),
    st.sampled_from(["", "\r", " # comment", "#"]),
    st.booleans(),
)
def test_line_protocol_on_near_valid_records(fields, sep, tail, missing):
    line = ("MISSING" + sep if missing else "") + sep.join(fields) + tail
    _parse_line_both(line)
    _parse_line_both(line.encode("utf-8"))


@given(st.binary(max_size=600))
def test_line_tracker_reads_whatever_streams_in(stream):
    trk = LineTracker(PORT, timeout=0.001)
    trk.port = _FakePort(b"")  # type: ignore[assignment]
    trk.port.buf += stream  # type: ignore[union-attr]
    for _ in range(5):
        try:
            sample = trk.sample()
        except TrackerError:
            continue
        assert checked_tracker_sample(sample) is sample


# ------------------------------------------------------------------------------------------------
# CRC
# ------------------------------------------------------------------------------------------------
@given(
    st.binary(max_size=300),
    st.integers(0, 300),
    st.one_of(st.binary(max_size=6), st.text(max_size=6), st.integers(-(2**40), 2**40)),
)
def test_crc_on_anything(data, cut, field):
    value = crc16(data)
    assert 0 <= value <= 0xFFFF
    assert crc16(data[cut:], crc16(data[:cut])) == value  # incremental = whole
    assert check(data, crc16_hex(data)) and check(data, value)
    assert isinstance(check(data, field), bool)  # a garbled field never raises


# ------------------------------------------------------------------------------------------------
# CAN frames
# ------------------------------------------------------------------------------------------------
def _config(cpm: float, zero: float, sign: int) -> CanBusConfig:
    legs = [
        LegEncoderConfig(
            leg=k,
            node_id=0x20 + k,
            counts_per_mm=cpm if k == 3 else 1000.0,
            sign=sign,
            zero_mm=zero,
        )
        for k in range(1, 7)
    ]
    return default_can_config(sync_period_s=0.0, legs=legs)


scales = st.tuples(
    st.floats(min_value=5e-324, max_value=1e300, allow_nan=False, allow_infinity=False),
    st.floats(allow_nan=False, allow_infinity=False),
    st.sampled_from([1, -1]),
)
# Mostly the configured position TPDOs (TPDO2: 0x2A1..0x2A6), their heartbeats, SYNC, and anything else.
cob_ids = st.one_of(
    st.integers(0x2A1, 0x2A6),
    st.sampled_from([0x080, 0x000, 0x723, 0x7FF]),
    st.integers(0x721, 0x726),
    st.integers(0, 0x1FFFFFFF),
)


@st.composite
def can_frames(draw) -> can.Message:
    cid = draw(cob_ids)
    return can.Message(
        arbitration_id=cid,
        is_extended_id=cid > 0x7FF or draw(st.integers(0, 3)) == 0,
        is_error_frame=draw(st.integers(0, 9)) == 0,
        is_remote_frame=draw(st.integers(0, 9)) == 0,
        data=draw(st.binary(max_size=8)),
        timestamp=draw(
            st.one_of(
                st.just(0.0),
                st.floats(1.7e9, 1.8e9),  # a wall-clock stamp, as SocketCAN and virtual give
                st.floats(),  # anything: NaN, inf, negative, huge
            )
        ),
    )


@given(scales, st.lists(can_frames(), max_size=20))
def test_tpdo_decoding_of_arbitrary_frames(scale, frames):
    cfg = _config(*scale)
    dec = TpdoDecoder(cfg)
    for msg in frames:
        try:
            out = decode_tpdo(msg, dec)
        except EncoderError as exc:
            assert str(exc)
            out = "error"
        else:
            if out is not None:
                leg, mm = out
                assert 1 <= leg <= 6 and math.isfinite(mm)
        if msg.is_error_frame:
            assert isinstance(describe_error_frame(msg), str)
    full = [m for m in frames if len(m.data) >= 4 and not m.is_extended_id]
    if full:
        ids = np.array([m.arbitration_id for m in full])
        payload = np.array([list(m.data[:4]) for m in full], np.uint8)
        legs, mm = dec.decode_batch(ids, payload)
        assert np.all((legs >= 0) & (legs <= 6))
        assert np.all(np.isfinite(mm) | np.isnan(mm))
        assert np.all(np.isnan(mm[legs == 0]))


@given(scales, st.lists(can_frames(), max_size=60), st.lists(st.floats(0, 0.05), max_size=60))
def test_can_receive_path_on_arbitrary_traffic(scale, frames, gaps):
    """The driver's whole receive path (clock offset and jumps, SYNC attribution, heartbeats,
    error frames) fed any traffic: it never raises, and every set it gives is honest — complete
    only with six finite readings and no fault, no reading ever infinite."""
    drv = LegEncoders(_config(*scale), listen_only=True)
    t = 1000.0
    for i, msg in enumerate(frames):
        t += gaps[i] if i < len(gaps) else 0.001
        drv._dispatch(msg, t)
    with drv._lock:
        drv._close_all()
    sets = list(drv._queue)
    assert [s.index for s in sets] == list(range(len(sets)))
    for s in sets:
        assert s.readings_mm.shape == (6,)
        assert np.all(np.isfinite(s.readings_mm) | np.isnan(s.readings_mm))
        assert s.complete == (bool(np.all(np.isfinite(s.readings_mm))) and not s.faults)
        sample = s.to_leg_sample()
        assert sample.complete == s.complete
    assert isinstance(drv.status(), dict)


# ------------------------------------------------------------------------------------------------
# The CAN configuration file
# ------------------------------------------------------------------------------------------------
json_scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**70), 2**70),
    st.floats(),
    st.text(max_size=12),
)


def _valid_config() -> dict:
    return default_can_config().model_dump()


@st.composite
def config_documents(draw) -> dict:
    """A valid configuration with a few values replaced by anything JSON can say."""
    doc = _valid_config()
    for _ in range(draw(st.integers(1, 4))):
        if draw(st.booleans()):
            key = draw(st.sampled_from(sorted(doc)))
            doc[key] = draw(json_scalars)
        else:
            leg = draw(st.integers(0, 5))
            key = draw(st.sampled_from(["leg", "node_id", "counts_per_mm", "sign", "zero_mm"]))
            if isinstance(doc["legs"], list) and len(doc["legs"]) > leg:
                doc["legs"][leg][key] = draw(json_scalars)
    return doc


def _load(tmp_path, name: str, content: bytes) -> None:
    path = tmp_path / name
    path.write_bytes(content)
    try:
        cfg = load_can_config(path)
    except CanConfigError as exc:
        assert str(path) in str(exc)
    else:
        assert isinstance(cfg, CanBusConfig)
        for leg in cfg.legs:
            assert math.isfinite(leg.counts_per_mm) and leg.counts_per_mm > 0
            assert math.isfinite(leg.zero_mm)
        LegEncoders(cfg)  # every accepted configuration is one the driver takes


@given(st.binary(max_size=300), st.sampled_from(["can.json", "can.toml"]))
@example(b"[" * 5000, "can.json")
@example(b"a = " + b"[" * 5000, "can.toml")
@example(b'{"heartbeat_timeout_s": 1e999}', "can.json")
@example(b"heartbeat_timeout_s = inf", "can.toml")
def test_can_config_file_on_arbitrary_bytes(tmp_path, content, name):
    _load(tmp_path, name, content)


@given(config_documents())
@example({"sync_period_s": 5e-324})  # a denormal period: half of it is 0, no deadline at all
def test_can_config_file_on_mutated_documents(tmp_path, doc):
    _load(tmp_path, "can.json", json.dumps(doc).encode())


# ------------------------------------------------------------------------------------------------
# The replay capture reader (mock_hw)
# ------------------------------------------------------------------------------------------------
def _spy(records: list[tuple[str, bytes]]) -> str:
    out = io.StringIO()
    fmt = FormatHexdump(out, False)
    for direction, data in records:
        if direction == "TX":
            fmt.tx(data)
        elif direction == "RX":
            fmt.rx(data)
        else:
            fmt.control(direction, data.decode("ascii"))
    return out.getvalue()


def _parse_capture_checked(text: str) -> None:
    try:
        chunks = parse_capture(text, "fuzz.txt")
    except CaptureError as exc:
        assert "fuzz.txt" in str(exc)
        return
    for c in chunks:
        assert isinstance(c, CaptureChunk) and c.direction in ("TX", "RX") and c.data
        assert c.rows and c.line_at(len(c.data) - 1) >= 1


capture_records = st.lists(
    st.tuples(
        st.sampled_from(["TX", "RX", "BRK", "Q-RX"]),
        st.binary(max_size=40),
    ).map(lambda r: (r[0], r[1] if r[0] in ("TX", "RX") else b"active")),
    max_size=8,
)


@given(st.text(max_size=400))
def test_replay_capture_on_arbitrary_text(text):
    _parse_capture_checked(text)


@given(capture_records, st.data())
def test_replay_capture_on_mutated_spy_output(records, data):
    text = _spy(records).encode("ascii")
    _parse_capture_checked(data.draw(mutated(text, text=True)).decode("latin-1"))


@given(st.text(max_size=80))
def test_replay_hex_row_and_url(field):
    try:
        row = parse_hex_row(field)
    except ValueError as exc:
        assert str(exc)
    else:
        assert 1 <= len(row) <= 16
    try:
        path = capture_path("ndireplay://" + field)
    except serial.SerialException:
        return
    assert path and "?" not in path


# ------------------------------------------------------------------------------------------------
# The mock tracker's command interpreter (mock_hw): it parses what the driver sends
# ------------------------------------------------------------------------------------------------
KNOWN_COMMANDS = [
    "INIT:", "PINIT:01", "PENA:01D", "TSTART:", "TX:0001", "BX:0001", "PHSR:00", "COMM:50000",
    "TSTOP:", "RESET:0", "VER:4", "PHSR:-1", "TX:zz", "PENA:01", "PHF:GG", "BEEP:1",
]  # fmt: skip
commands = st.one_of(
    st.binary(max_size=60),
    st.sampled_from([c.encode() + crc16_hex(c.encode()) for c in KNOWN_COMMANDS]),
    st.text(alphabet=string.ascii_uppercase + string.digits + ": -_\x00", max_size=20).map(
        str.encode
    ),
)


@functools.cache
def _mock_tracker() -> MockNDITracker:
    return MockNDITracker(MockRobot(left_hand(), seed=3), seed=3, frame_rate_hz=1000.0)


@given(st.lists(commands, max_size=8))
def test_mock_tracker_interprets_whatever_the_host_sends(lines):
    dev = _mock_tracker()
    dev.on_break()  # a fresh device state for every example
    for line in lines:
        dev.feed(line + b"\r")
    out = dev.read(1 << 20, 0.0)
    assert out is None or isinstance(out, bytes)
