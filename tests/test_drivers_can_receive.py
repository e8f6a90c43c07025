"""The CAN driver's receive path (drivers/can_receive.py) fed frames directly, no bus: a
listen-only driver (its sets opened by the SYNCs it sees) handles SYNCs, positions and EMCYs
stamped on a bus clock the test chooses, so where each frame falls — which set it flags, how
late it was — is known exactly. The bus-level contract is tests/test_drivers_can_encoders.py."""

from __future__ import annotations

import re
import time
from types import SimpleNamespace

import can
import pytest

from hexcal.drivers.can_config import CanBusConfig, LegEncoderConfig
from hexcal.drivers.can_encoders import LegEncoders

DEADLINE_S = 0.008


def _driver(listen_only: bool = True, deadline_s: float = DEADLINE_S) -> LegEncoders:
    """A driver of six legs, nodes 0x21–0x26, 1000 counts/mm, an 8 ms deadline; listen-only
    unless asked (then it produces the SYNCs)."""
    legs = [
        LegEncoderConfig(leg=k + 1, node_id=0x21 + k, counts_per_mm=1000.0, sign=1, zero_mm=0.0)
        for k in range(6)
    ]
    config = CanBusConfig(
        interface="virtual",
        channel="receive-path-bus",
        legs=legs,
        sync_period_s=max(0.01, 2 * deadline_s),  # the deadline must be under a period
        heartbeat_timeout_s=10.0,
        max_tpdo_delay_s=deadline_s,
        sync_counter=240,
    )
    return LegEncoders(config, listen_only=listen_only)


def _frame(cob: int, data: bytes, ts: float) -> can.Message:
    return can.Message(arbitration_id=cob, data=data, timestamp=ts, is_extended_id=False)


def _sync(counter: int, ts: float) -> can.Message:
    return _frame(0x80, bytes([counter]), ts)


def _position(leg: int, mm: float, ts: float) -> can.Message:
    """Leg ``leg``'s position frame (its node's TPDO2, 0x280 + node id)."""
    cob = 0x280 + 0x20 + leg
    return _frame(cob, round(mm * 1000).to_bytes(4, "little", signed=True), ts)


def _feed(drv: LegEncoders, frames: list[tuple[can.Message, float]]) -> list:
    """Each frame handled at its host arrival time; then every open set closed."""
    for msg, t in frames:
        drv._dispatch(msg, t)
    with drv._lock:
        drv._close_all()
    return list(drv._queue)


def _positions(ts: float, legs=range(1, 7)) -> list[tuple[can.Message, float]]:
    return [(_position(k, 100.0 + k, ts), ts + 1e-4) for k in legs]


def test_a_late_position_flags_its_set_with_how_late_it_was():
    """Leg 2's position stamped 62.5 ms after its SYNC (the limit 8 ms; no later SYNC): its set
    is flagged, the message giving 62.5 ms (to 0.05 ms: its one decimal) and the limit; the
    other legs' positions, 1 ms after the SYNC, are not."""
    t0 = 1000.0
    frames = [(_sync(5, t0), t0)] + _positions(t0 + 0.001, (1, 3, 4, 5, 6))
    frames += [(_position(2, 102.0, t0 + 0.0625), t0 + 0.0626)]
    (s,) = _feed(_driver(), frames)
    assert not s.complete and s.readings_mm[1] == pytest.approx(102.0)
    (late,) = [f for f in s.faults if "arrived" in f]
    m = re.match(
        r"leg 2 encoder \(node 0x22\) position arrived ([\d.]+) ms after SYNC 5 \(limit ([\d.]+) ms\)",
        late,
    )
    assert m, late
    assert float(m[1]) == pytest.approx(62.5, abs=0.05)
    assert float(m[2]) == pytest.approx(1e3 * DEADLINE_S, abs=0.05)


def test_an_emergency_flags_the_set_its_bus_time_falls_in_not_the_newest():
    """Two SYNCs 10 ms apart, then leg 3's EMCY stamped 5 ms after the first (handled after the
    second): the first set carries it, the second does not (its node reported no error
    register, so the error does not carry on to later sets)."""
    t0 = 1000.0
    emcy = _frame(0x80 + 0x23, bytes([0x10, 0x82, 0x00, 0, 0, 0, 0, 0]), t0 + 0.005)
    frames = [(_sync(1, t0), t0)] + _positions(t0 + 0.001)
    frames += [(_sync(2, t0 + 0.010), t0 + 0.010), (emcy, t0 + 0.0105)]
    frames += _positions(t0 + 0.011)
    first, second = _feed(_driver(), frames)
    assert any(f.startswith("leg 3 encoder (node 0x23) sent EMCY 0x8210") for f in first.faults)
    assert not first.complete
    assert second.complete and not second.faults


def test_a_position_stamped_at_a_closed_sets_sync_is_discarded_as_late_not_an_orphan():
    """Set 1 closed (a position of set 2 came after its answers were due); then leg 1's
    position stamped at set 1's own SYNC time arrives: it belonged to that set, so it is
    discarded quietly as late — no 'outside any SYNC window' fault on the set open now."""
    t0 = 1000.0
    frames = [(_sync(1, t0), t0)] + _positions(t0 + 0.001)
    frames += [(_sync(2, t0 + 0.010), t0 + 0.010)] + _positions(t0 + 0.012)
    frames += [(_position(1, 101.0, t0), t0 + 0.0125)]
    drv = _driver()
    first, second = _feed(drv, frames)
    assert first.complete and second.complete, (first.faults, second.faults)
    assert drv._late_discarded == 1


@pytest.mark.parametrize(
    ("cls", "ctrl", "state"),
    [
        (0x004, 0x10, "ERROR-PASSIVE"),  # the controller's own report: RX error-passive
        (0x004, 0x40, "ACTIVE"),  # ... back to error-active
        (0x008, 0x10, "ACTIVE"),  # a protocol violation: its data byte 1 is no controller state
        (0x008 | 0x004, 0x20, "ERROR-PASSIVE"),  # both: the controller's part counts
    ],
)
def test_only_a_controller_error_frame_moves_the_bus_state(cls, ctrl, state):
    """An error frame changes the bus state only through its controller class (CAN_ERR_CRTL)
    and that byte; a protocol violation's data say nothing about the controller."""
    drv = _driver()
    err = can.Message(
        arbitration_id=0x20000000 | cls,
        is_error_frame=True,
        is_extended_id=True,
        data=bytes([0, ctrl, 0x08, 0, 0, 0, 0, 0]),
        timestamp=1000.0,
    )
    drv._dispatch(err, 1000.0)
    assert drv.status()["bus_state"] == state


def test_the_echo_of_the_drivers_own_sync_gives_its_set_the_wire_time():
    """A producing driver (network stubbed: the SYNC's transmit returns at once) on a bus that
    marks its echoes: the echo of its SYNC, stamped 0.2 s after the driver stamped the SYNC
    before sending (the host stalled; within half the 1 s deadline of it), moves the set's
    SYNC time to the echo's — the exact wire time — and positions count from there."""
    drv = _driver(listen_only=False, deadline_s=1.0)
    drv._network = SimpleNamespace(sync=SimpleNamespace(transmit=lambda counter: None))
    t = time.monotonic()
    drv._dispatch(_frame(0x721, bytes([5]), t), t)  # a heartbeat: the bus clock learnt, offset 0
    drv._send_sync_locked()
    echo = can.Message(
        arbitration_id=0x80, data=bytes([1]), timestamp=t + 0.2, is_rx=False, is_extended_id=False
    )
    drv._dispatch(echo, t + 0.2)
    (s,) = _feed(drv, _positions(t + 0.2005))
    assert s.sync_counter == 1 and s.t_sync == pytest.approx(t + 0.2, abs=1e-9)
    assert s.arrival == pytest.approx([t + 0.2005] * 6, abs=1e-9)


def test_a_short_position_frame_is_named_and_gives_no_reading():
    """Leg 4's position frame with 3 data bytes (a 32-bit position needs 4): its set has no
    reading for leg 4 and says which leg sent how many bytes; the other legs read as sent."""
    t0 = 1000.0
    short = _frame(0x280 + 0x24, bytes([1, 2, 3]), t0 + 0.001)
    frames = [(_sync(1, t0), t0)] + _positions(t0 + 0.001, (1, 2, 3, 5, 6))
    frames += [(short, t0 + 0.0012)]
    (s,) = _feed(_driver(), frames)
    assert s.readings_mm[3] != s.readings_mm[3]  # NaN
    assert s.readings_mm[[0, 1, 2, 4, 5]] == pytest.approx([101.0, 102.0, 103.0, 105.0, 106.0])
    assert any(f.startswith("leg 4 encoder (node 0x24) sent a 3-byte TPDO2") for f in s.faults)


def test_a_position_stamped_off_the_bus_clock_is_charged_to_its_own_leg():
    """Leg 5's position stamped 5 s before the bus clock learnt from the SYNC (its stamp not
    trusted): it is discarded, and the note names leg 5 and the stamp 5 s early (−5.000 s)."""
    t0 = 1000.0
    frames = [(_sync(1, t0), t0)] + _positions(t0 + 0.001, (1, 2, 3, 4, 6))
    frames += [(_position(5, 105.0, t0 + 0.001 - 5.0), t0 + 0.001)]
    (s,) = _feed(_driver(), frames)
    assert s.readings_mm[4] != s.readings_mm[4]
    (note,) = [f for f in s.faults if "off the clock" in f]
    assert note.startswith("leg 5 encoder (node 0x25) sent a position stamped -5.000 s off"), note
