"""The position's edge values through the real driver (drivers/can_frames.py's decoder, the set-up
in can_nodes.py, can_receive.py's frame handling) and the mock encoders (mock_hw/can_encoders.py,
can_node.py): UNSIGNED32 counts at and above 2³¹, INTEGER32 negatives, a position that wraps at a
16-bit range and at 2³², and each data type of 0x6004 an EDS can give — INTEGER32 and
UNSIGNED32 read, any other refused by name at set-up.

A decoder that reads UNSIGNED32 as signed puts counts ≥ 2³¹ 2³² counts (4.3 km at 1000
counts/mm) low: every test here with such counts fails on it.
"""

from __future__ import annotations

import uuid
from pathlib import Path

import can
import numpy as np
import pytest

from hexcal.drivers.can_config import CanBusConfig, LegEncoderConfig
from hexcal.drivers.can_encoders import EncoderError, LegEncoders, TpdoDecoder
from hexcal.drivers.can_nodes import NodeInfo
from hexcal.mock_hw.can_encoders import MockEncoderNodes
from hexcal.mock_hw.eds_files import mock_eds
from hexcal.mock_hw.robot import DEFAULT_NOISE, MockRobot
from hexcal.sim.robots import left_hand

CPM = 1000.0
#: 0x6004's data type codes in an EDS (CiA 301).
EDS_TYPES = {
    "INTEGER8": 0x0002,
    "INTEGER16": 0x0003,
    "INTEGER32": 0x0004,
    "UNSIGNED8": 0x0005,
    "UNSIGNED16": 0x0006,
    "UNSIGNED32": 0x0007,
    "REAL32": 0x0008,
    "INTEGER64": 0x0015,
    "UNSIGNED64": 0x001B,
}


def _info(leg: int, position_type: str, total_range: int | None = None) -> NodeInfo:
    """What the set-up reports of leg ``leg``'s node, as far as decoding reads it."""
    return NodeInfo(
        leg=leg,
        node_id=0x20 + leg,
        device_type=0x00020196,
        vendor_id=None,
        product_code=None,
        revision=None,
        serial=None,
        position_type=position_type,
        total_range=total_range,
        operating_parameters=None,
        preset=None,
        step_nm=None,
        tpdo=2,
        tpdo_cob_id=0x280 + 0x20 + leg,
        heartbeat_ms=100,
        sync_overflow=0,
        eds="",
    )


def _config(zero: list[float], sign: list[int] | None = None, **kw) -> CanBusConfig:
    sign = sign or [1] * 6
    legs = [
        LegEncoderConfig(
            leg=k + 1, node_id=0x21 + k, counts_per_mm=CPM, sign=sign[k], zero_mm=zero[k]
        )
        for k in range(6)
    ]
    base = {"sync_period_s": 0.01, "heartbeat_timeout_s": 0.5}
    return CanBusConfig(legs=legs, **{**base, **kw})


def _frame(leg: int, raw: bytes) -> can.Message:
    return can.Message(arbitration_id=0x280 + 0x20 + leg, data=raw, is_extended_id=False)


def _decoder(position_type: str, total_range: int | None = None) -> TpdoDecoder:
    dec = TpdoDecoder(_config([0.0] * 6))
    dec.set_nodes([_info(k, position_type, total_range) for k in range(1, 7)])
    return dec


# -- decoding, no bus ----------------------------------------------------------------------------
UNSIGNED_COUNTS = [0, 1, 2**31 - 1, 2**31, 2**31 + 1, 3_000_000_000, 2**32 - 1]
SIGNED_COUNTS = [0, 1, -1, -300_000, 2**31 - 1, -(2**31)]


@pytest.mark.parametrize("counts", UNSIGNED_COUNTS)
def test_unsigned32_counts_at_and_above_2_31_are_positive(counts):
    dec = _decoder("UNSIGNED32")
    raw = counts.to_bytes(4, "little", signed=False)
    assert dec.decode(_frame(1, raw)) == (1, counts / CPM)
    legs, mm = dec.decode_batch(np.array([0x2A1]), np.frombuffer(raw, np.uint8)[None])
    assert legs[0] == 1 and mm[0] == counts / CPM


@pytest.mark.parametrize("counts", SIGNED_COUNTS)
def test_integer32_counts_keep_their_sign(counts):
    dec = _decoder("INTEGER32")
    raw = counts.to_bytes(4, "little", signed=True)
    assert dec.decode(_frame(2, raw)) == (2, counts / CPM)
    legs, mm = dec.decode_batch(np.array([0x2A2]), np.frombuffer(raw, np.uint8)[None])
    assert legs[0] == 2 and mm[0] == counts / CPM


def test_each_leg_is_decoded_by_its_own_node_type():
    """Odd legs UNSIGNED32, even legs INTEGER32: the same four bytes (2³¹ + 5 unsigned, −2³¹ + 5
    signed) read as each leg's node says, whichever leg's frame comes first."""
    dec = TpdoDecoder(_config([0.0] * 6))
    # The type names built at run time (as from a file), not the interned literals.
    names = {1: "".join(["UNSIGNED", "32"]), 0: "".join(["INTEGER", "32"])}
    dec.set_nodes([_info(k, names[k % 2]) for k in range(1, 7)])
    raw = (2**31 + 5).to_bytes(4, "little")
    for leg in (6, 1, 4, 3, 5, 2):
        want = (2**31 + 5) / CPM if leg % 2 else (-(2**31) + 5) / CPM
        assert dec.decode(_frame(leg, raw)) == (leg, want)
        legs, mm = dec.decode_batch(np.array([0x2A0 + leg]), np.frombuffer(raw, np.uint8)[None])
        assert legs[0] == leg and mm[0] == want


def test_each_leg_wraps_at_its_own_range():
    """Legs 1–3 wrap at 2¹⁶ counts, legs 4–6 have no range: 65,000 then 500 counts is a step of
    +1036 counts on the first, a fall of 64,500 on the others."""
    dec = TpdoDecoder(_config([0.0] * 6))
    dec.set_nodes([_info(k, "UNSIGNED32", 2**16 if k <= 3 else None) for k in range(1, 7)])
    for leg in (4, 1, 6, 3, 5, 2):
        dec.decode(_frame(leg, (65_000).to_bytes(4, "little")))
        got = dec.decode(_frame(leg, (500).to_bytes(4, "little")))[1]
        assert got == ((65_000 + 1036) / CPM if leg <= 3 else 500 / CPM), leg


def test_the_batch_path_takes_ids_beyond_11_bits_as_no_position():
    """Ids outside the 11-bit range (a 29-bit id from a log) are no position TPDO: leg 0, NaN."""
    dec = _decoder("UNSIGNED32")
    ids = np.array([0x800, 0x1FFFFFFF, 0x7FF, 0x2A1, 0])
    payload = np.tile(np.frombuffer((1234).to_bytes(4, "little"), np.uint8), (5, 1))
    legs, mm = dec.decode_batch(ids, payload)
    assert legs.tolist() == [0, 0, 0, 1, 0]
    assert np.isnan(mm[[0, 1, 2, 4]]).all() and mm[3] == 1.234


def test_a_remote_frame_on_a_position_id_is_no_position():
    """A remote request (RTR) with a TPDO's id carries no data: not a position, not an error."""
    dec = _decoder("UNSIGNED32")
    rtr = can.Message(arbitration_id=0x2A1, is_remote_frame=True, dlc=4, is_extended_id=False)
    assert dec.decode(rtr) is None


@pytest.mark.parametrize("n", [0, 1, 2, 3])
def test_a_tpdo_shorter_than_four_bytes_is_refused(n):
    dec = _decoder("UNSIGNED32")
    with pytest.raises(EncoderError, match=f"sent a {n}-byte TPDO2"):
        dec.decode(_frame(1, bytes(range(1, n + 1))))


@pytest.mark.parametrize("leg", range(1, 7))
def test_a_short_tpdo_names_its_own_leg(leg):
    dec = TpdoDecoder(_config([0.0] * 6, [1, -1, 1, -1, 1, -1]))
    with pytest.raises(EncoderError, match=rf"leg {leg} encoder \(node 0x{0x20 + leg:02X}\)"):
        dec.decode(_frame(leg, b"\x01\x02"))


@pytest.mark.parametrize(
    ("position_type", "span", "start"),
    [
        ("UNSIGNED32", 2**16, 2**16 - 3_500),  # a 16-bit position range (0x6002 = 65536)
        ("UNSIGNED32", 2**32, 2**32 - 3_500),  # the type's own range
        ("INTEGER32", 2**32, 2**31 - 3_500),  # INTEGER32 through +2³¹ − 1 → −2³¹
        ("UNSIGNED32", 36_001, 36_001 - 3_500),  # a range of an odd number of counts
    ],
)
def test_a_position_wrapping_at_its_range_continues(position_type, span, start):
    """Counts stepping +700 (and then back −700) through the wrap point read as a straight line:
    0.7 mm a step, never the range's jump."""
    dec = _decoder(position_type, span)
    signed = position_type == "INTEGER32"
    true = [start + 700 * i for i in range(12)] + [start + 700 * (11 - i) for i in range(12)]
    got = []
    for c in true:
        wire = c % span if not signed else (c + 2**31) % 2**32 - 2**31
        got.append(dec.decode(_frame(3, wire.to_bytes(4, "little", signed=signed)))[1])
    assert np.allclose(np.diff(got), np.sign(np.diff(true)) * 0.7, atol=1e-9)
    assert got[0] == pytest.approx(start / CPM)


# -- through the set-up, the mock encoders and the driver on python-can's virtual bus ------------
def _eds_with_position_type(tmp_path: Path, base: str, type_name: str) -> Path:
    """Mock EDS ``base`` with 0x6004 of data type ``type_name``."""
    text = mock_eds(base).read_text()
    head, sep, rest = text.partition("[6004]\n")
    assert sep, f"{base} has no [6004] section"
    section, blank, tail = rest.partition("\n\n")
    lines = [
        f"DataType=0x{EDS_TYPES[type_name]:04X}" if ln.startswith("DataType=") else ln
        for ln in section.splitlines()
    ]
    out = tmp_path / f"{base}_{type_name}.eds"
    out.write_text(head + sep + "\n".join(lines) + blank + tail)
    return out


def _run(config: CanBusConfig, eds: Path, n: int = 6) -> tuple[LegEncoders, np.ndarray, dict]:
    """The driver against six mock nodes from ``eds``: its node reports, ``n`` complete sets'
    readings (n, 6) mm, and what the mock latched {key: (6,) mm}."""
    robot = MockRobot(left_hand(), noise=DEFAULT_NOISE, seed=4)
    mock = MockEncoderNodes(robot, config, seed=1, eds=eds)
    mock.start()
    drv = LegEncoders(config)
    try:
        drv.start()
        sets = []
        for _ in range(50 * n):
            s = drv.read_set(timeout=1.0)
            if s.complete:
                sets.append(s)
            if len(sets) == n:
                break
        assert len(sets) == n, "too few complete sets"
        latched = mock.latched()
        sent = np.array(
            [latched[s.index + 1 if not s.sync_counter else s.sync_counter] for s in sets]
        )
        return drv, np.array([s.readings_mm for s in sets]), {"sent": sent}
    finally:
        drv.stop()
        mock.stop()


@pytest.mark.parametrize(
    ("base", "type_name", "zero", "sign", "lowest"),
    [
        # minimal: fixed mapping, no 0x6002. Counts 2³¹ + reading, 2³¹ + (2000 − reading) mm,
        # and just under 2³².
        (
            "minimal",
            "UNSIGNED32",
            [-(2**31) / CPM, 2**31 / CPM + 2000.0, -(2**32 - 10**6) / CPM] * 2,
            [1, -1, 1] * 2,
            2**31,
        ),
        # vendor-like: writable mapping. Negative counts: −(1000 − reading) mm and −2³¹ + reading.
        ("vendor", "INTEGER32", [1000.0, -1000.0, 2**31 / CPM] * 2, [1, -1, 1] * 2, -(2**31)),
        # the linear device (no 0x6002, no 0x1019), its position declared UNSIGNED32 in the EDS
        # the rig file gives (a vendor-like one could not: its 0x6002 wraps at 2²⁵ counts).
        (
            "linear",
            "UNSIGNED32",
            [-(2**31) / CPM, 2**31 / CPM + 2000.0, -(2**32 - 10**6) / CPM] * 2,
            [1, -1, 1] * 2,
            2**31,
        ),
    ],
)
def test_each_accepted_position_type_reads_the_robot(tmp_path, base, type_name, zero, sign, lowest):
    """Six nodes whose counts sit at the type's edge (UNSIGNED32 ≥ 2³¹, INTEGER32 < 0): the
    set-up names the type, and every complete set equals what the mock latched to a count."""
    eds = _eds_with_position_type(tmp_path, base, type_name)
    config = _config(
        zero, sign, interface="virtual", channel=f"edge-{uuid.uuid4().hex[:8]}-bus", eds=str(eds)
    )
    if base == "vendor":
        config = replace_sync_counter(config)
    drv, readings, seen = _run(config, eds)
    assert [n.position_type for n in drv.nodes] == [type_name] * 6
    assert np.all(np.abs(readings - seen["sent"]) <= 0.5 / CPM + 1e-9)
    counts = [config.leg(k + 1).mm_to_counts(readings[0, k]) for k in range(6)]
    if lowest > 0:
        assert min(counts) >= lowest and max(counts) < 2**32, counts
    else:
        assert max(counts) < 0 and min(counts) >= lowest, counts


def replace_sync_counter(config: CanBusConfig) -> CanBusConfig:
    """The vendor-like device has 0x1019: SYNC with a counter, as the contract tests run it."""
    return config.model_copy(update={"sync_counter": 240})


@pytest.mark.parametrize(
    "type_name",
    ["INTEGER8", "INTEGER16", "UNSIGNED8", "UNSIGNED16", "REAL32", "INTEGER64", "UNSIGNED64"],
)
def test_a_position_type_hexcal_cannot_read_is_refused_by_name(tmp_path, type_name):
    """hexcal maps 0x6004 as 32 bits and reads it as INTEGER32 or UNSIGNED32; an EDS typing it
    otherwise (a 16-bit position, a REAL32) is refused at set-up, naming the leg, the object and
    the type, rather than decoded as something else."""
    eds = _eds_with_position_type(tmp_path, "vendor", type_name)
    config = _config(
        [0.0] * 6,
        interface="virtual",
        channel=f"edge-{uuid.uuid4().hex[:8]}-bus",
        eds=str(eds),
        sync_counter=240,
    )
    robot = MockRobot(left_hand(), noise=DEFAULT_NOISE, seed=4)
    mock = MockEncoderNodes(robot, config, seed=1, eds=eds)
    mock.start()
    drv = LegEncoders(config)
    try:
        with pytest.raises(
            EncoderError, match=rf"leg 1 .*0x6004 \(position value\) is {type_name} "
        ):
            drv.start()
    finally:
        drv.stop()
        mock.stop()
