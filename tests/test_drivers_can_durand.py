"""The set-up and the reading of sets against an independent CANopen stack: durand (PyPI, MIT),
a pure-Python CANopen *responder* library that shares no code with canopen (which hexcal's
driver and mocks use) nor with hexcal. Its nodes have their own SDO server, NMT slave,
heartbeat producer, SYNC consumer and TPDOs (COB-IDs with the no-RTR bit 30 set), and store
the EDS they generate from their object dictionary at 0x1021 — which hexcal reads and uses.

Only the CiA 406 objects are added here (0x1000 device type, 0x6004 position value); the rest is
durand's. Installed with the ``interop`` extra (``pip install -e '.[test,interop]'``, as CI
does); skipped, saying so, where durand is not installed.
"""

from __future__ import annotations

import threading
import uuid

import can
import pytest

durand = pytest.importorskip(
    "durand",
    reason="durand (the independent CANopen stack) is not installed: pip install -e '.[test,interop]'",
)

from durand import CANBusNetwork, MinimalNode, Variable, set_scheduler  # noqa: E402
from durand import DatatypeEnum as DT  # noqa: E402
from durand.scheduler import SyncScheduler  # noqa: E402

from hexcal.drivers.can_config import CanBusConfig, LegEncoderConfig  # noqa: E402
from hexcal.drivers.can_encoders import LegEncoders  # noqa: E402
from hexcal.drivers.can_nodes import EDS_DEVICE  # noqa: E402

#: Faults a busy host causes: durand answers from Python threads, stamped when sent.
TIMING = ("arrived", "sent no position", "sent two positions", "outside any SYNC window")


def counts(k: int) -> int:
    return 300_000 + 1000 * k


@pytest.fixture
def durand_nodes():
    """Six durand nodes (one python-can bus handle each, as six devices), CiA 406 multi-turn
    rotary encoders with an UNSIGNED32 position: (channel, nodes)."""
    channel = f"hexcal-durand-{uuid.uuid4().hex[:8]}-bus"
    sched = SyncScheduler()
    set_scheduler(sched)
    runner = threading.Thread(target=sched.run, name="durand-scheduler", daemon=True)
    runner.start()
    made = []
    try:
        for k in range(1, 7):
            bus = can.Bus(interface="virtual", channel=channel)
            net = CANBusNetwork(bus)
            with sched.lock:
                node = MinimalNode(net, 0x20 + k)
                od = node.object_dictionary
                od[0x1000] = Variable(DT.UNSIGNED32, "ro", 0x00020196, name="Device type")
                od[0x6004] = Variable(DT.UNSIGNED32, "ro", counts(k), name="Position value")
            made.append((bus, net, node))
        yield channel, [n for _, _, n in made]
    finally:
        with sched.lock:
            for _, _, node in made:  # heartbeat off: no timer left to fire on a closed bus
                node.object_dictionary.write(0x1017, 0, 0)
        sched.stop()
        runner.join(timeout=2.0)
        assert not runner.is_alive()
        for bus, net, _ in made:
            net.stop()
            bus.shutdown()


def test_an_independent_stack_is_set_up_from_the_eds_it_stores_and_read(durand_nodes):
    channel, nodes = durand_nodes
    legs = [LegEncoderConfig(leg=k, node_id=0x20 + k, counts_per_mm=1000.0) for k in range(1, 7)]
    # A 20 ms SYNC and a 15 ms answer deadline: durand's nodes are Python threads of this
    # process, not encoders latching in hardware.
    cfg = CanBusConfig(
        interface="virtual",
        channel=channel,
        legs=legs,
        sync_period_s=0.02,
        max_tpdo_delay_s=0.015,
        heartbeat_timeout_s=0.5,
    )
    with LegEncoders(cfg) as drv:
        sets = [drv.read_set(1.0) for _ in range(50)]
        infos = list(drv.nodes)
    other = [f for s in sets for f in s.faults if not any(w in f for w in TIMING)]
    assert not other
    complete = [s for s in sets if s.complete]
    assert len(complete) >= 45, [f for s in sets for f in s.faults]
    for s in complete:
        assert list(s.readings_mm) == [counts(k) / 1000 for k in range(1, 7)]
    for info in infos:
        assert info.eds_source == EDS_DEVICE  # durand's own EDS, read from 0x1021
        assert info.position_type == "UNSIGNED32" and info.device_type == 0x00020196
        assert info.tpdos == (1, 2, 3, 4) and info.tpdo_highest == (3, 3, 3, 3)
        assert info.heartbeat_ms == 125
    for node in nodes:
        od = node.object_dictionary
        # TPDO2 valid on every SYNC, at its predefined COB-ID, the no-RTR bit as durand had it.
        assert od.read(0x1801, 1) == 0x40000280 + node.node_id and od.read(0x1801, 2) == 1
        assert od.read(0x1A01, 0) == 1 and od.read(0x1A01, 1) == 0x60040020
        assert od.read(0x1800, 1) & 0x80000000  # TPDO1 disabled
