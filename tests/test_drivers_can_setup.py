"""The encoders' set-up over SDO, against nodes at their CiA 406 factory settings: hexcal's mock
(canopen LocalNodes with the generic EDS) and a slave that is not hexcal's (canopen's own
LocalNode, NMT slave and heartbeat producer, from a vendor-like EDS with an UNSIGNED32 position
that wraps), faults included: EMCY, a device that is not an encoder, an SDO abort, a node that
does not answer SDO, a node out of its box at another node id (LSS)."""

from __future__ import annotations

import itertools
import threading
import time
import uuid
from pathlib import Path

import can
import canopen
import numpy as np
import pytest

from hexcal.app.cli import main
from hexcal.drivers.can_config import CanBusConfig, LegEncoderConfig
from hexcal.drivers.can_emcy import Emergency, emcy_text
from hexcal.drivers.can_encoders import EncoderError, EncoderSilent, LegEncoders
from hexcal.drivers.can_nodes import generic_eds
from hexcal.mock_hw.can_encoders import MockEncoderNodes
from hexcal.mock_hw.robot import DEFAULT_NOISE, MockRobot
from hexcal.sim.robots import left_hand

SYNC_S = 0.01


def config(channel: str, **kw) -> CanBusConfig:
    legs = [LegEncoderConfig(leg=k, node_id=0x20 + k, counts_per_mm=1000.0) for k in range(1, 7)]
    base = {"sync_period_s": SYNC_S, "heartbeat_timeout_s": 0.5}
    return CanBusConfig(interface="virtual", channel=channel, legs=legs, **{**base, **kw})


@pytest.fixture
def channel() -> str:
    return f"hexcal-setup-{uuid.uuid4().hex[:8]}-bus"


@pytest.fixture
def robot() -> MockRobot:
    return MockRobot(left_hand(), noise=DEFAULT_NOISE, seed=4)


#: Words of the faults a loaded machine causes (a frame handled late): timing, not set-up.
TIMING = ("arrived", "sent no position", "outside any SYNC window")


def not_timing(sets) -> list[str]:
    """The faults of ``sets`` that are not about timing."""
    return [f for s in sets for f in s.faults if not any(w in f for w in TIMING)]


class Sniffer:
    """Every frame on the channel, from another bus handle (a bus analyser)."""

    def __init__(self, channel: str):
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.frames: list[can.Message] = []
        self.notifier = can.Notifier(self.bus, [self.frames.append], timeout=0.05)

    def ids(self, since: int = 0) -> list[int]:
        return [m.arbitration_id for m in self.frames[since:]]

    def close(self) -> None:
        self.notifier.stop()
        self.bus.shutdown()


def test_without_configuration_factory_encoders_give_no_reading_set(robot, channel):
    """The old driver — NMT start, SYNC with a counter, listen on TPDO1 — against encoders at
    their factory settings: no heartbeat (0x1017 = 0), so none is seen to start; and once a
    heartbeat is on, TPDO1 is cyclic (every 100 ms, not on SYNC) and the counter byte is a
    protocol error to them (EMCY 0x8240): almost every set is flagged."""
    old = config(channel, configure=False, tpdo=1, sync_counter=240)
    with MockEncoderNodes(robot, old):
        with pytest.raises(EncoderSilent) as exc:
            LegEncoders(old).start(timeout=0.3)
        assert exc.value.legs == (1, 2, 3, 4, 5, 6)
        # Someone turns the heartbeats on by hand: the old driver starts, and reads rubbish.
        net = canopen.Network()
        net.connect(interface="virtual", channel=channel)
        for leg in old.legs:
            net.add_node(leg.node_id, str(generic_eds())).sdo[0x1017].raw = 50
        net.disconnect()
        drv = LegEncoders(old).start(timeout=1.0)
        try:
            sets = [drv.read_set(1.0) for _ in range(40)]
        finally:
            drv.stop()
    complete = sum(s.complete for s in sets)
    assert complete <= 4, complete
    faults = " ".join(f for s in sets for f in s.faults)
    assert "EMCY 0x8240 (unexpected SYNC data length)" in faults
    assert "sent no position for SYNC" in faults or "outside any SYNC window" in faults


def test_hexcal_configures_factory_encoders_and_reads_them_on_sync(robot, channel):
    cfg = config(channel)
    sniff = Sniffer(channel)
    try:
        with MockEncoderNodes(robot, cfg) as nodes, LegEncoders(cfg) as drv:
            sets = [drv.read_set(1.0) for _ in range(60)]
            st = drv.status()
            mark = len(sniff.frames)
            time.sleep(0.3)
            later = sniff.frames[mark:]
            assert all(nodes.encoders[k].value(0x1017) == 125 for k in range(1, 7))
            assert all(nodes.encoders[k].value(0x1801, 2) == 1 for k in range(1, 7))
            assert all(nodes.encoders[k].value(0x1800, 1) & 0x80000000 for k in range(1, 7))
    finally:
        sniff.close()
    # A loaded machine delays a frame now and then (flagged late, never lost): the rest are
    # complete, and no flag is about the set-up.
    assert sum(s.complete for s in sets) >= 54, [f for s in sets for f in s.faults]
    assert not not_timing(sets)
    assert st["sync_counter"] == 0
    # SYNC without a counter byte, as the nodes' 0x1019 = 0 asks; no cyclic TPDO1, no EMCY.
    syncs = [m for m in later if m.arbitration_id == 0x080]
    assert syncs and all(m.dlc == 0 for m in syncs)
    ids = {m.arbitration_id for m in later}
    assert ids.isdisjoint(range(0x1A1, 0x1A7)) and ids.isdisjoint(range(0x0A1, 0x0A7))
    assert set(range(0x2A1, 0x2A7)) <= ids and set(range(0x721, 0x727)) <= ids
    for k, leg in enumerate(st["legs"]):
        node = leg["node"]
        assert node["serial"] == 4_060_001 + k and node["product_code"] == 0x406
        assert node["encoder_type"] == "absolute linear encoder"
        assert (node["tpdo"], node["tpdo_cob_id"], node["heartbeat_ms"]) == (2, 0x2A1 + k, 125)
        assert node["position_type"] == "INTEGER32" and node["total_range"] is None


def test_a_sync_counter_set_in_the_rig_file_is_written_to_every_node(robot, channel):
    cfg = config(channel, sync_counter=240)
    with MockEncoderNodes(robot, cfg) as nodes, LegEncoders(cfg) as drv:
        sets = [drv.read_set(1.0) for _ in range(30)]
        assert all(nodes.encoders[k].value(0x1019) == 240 for k in range(1, 7))
    assert sum(s.complete for s in sets) >= 24 and not not_timing(sets)
    counters = [s.sync_counter for s in sets]
    assert all(b == a % 240 + 1 for a, b in itertools.pairwise(counters))


def test_emcy_flags_the_sets_with_its_meaning_until_the_error_reset(robot, channel):
    cfg = config(channel)
    with MockEncoderNodes(robot, cfg) as nodes, LegEncoders(cfg) as drv:
        [drv.read_set(1.0) for _ in range(5)]
        nodes.emergency(3, 0x7300, 0x81)
        during = [drv.read_set(1.0) for _ in range(10)]
        nodes.emergency(3, 0x0000, 0x00)
        [drv.read_set(1.0) for _ in range(3)]
        after = [drv.read_set(1.0) for _ in range(10)]
        assert drv.status()["emergencies"] == 2
    flagged = [s for s in during if not s.complete]
    assert len(flagged) >= 8
    assert any(
        "leg 3 encoder (node 0x23) sent EMCY 0x7300 (sensor), error register 0x81" in f
        for s in flagged
        for f in s.faults
    )
    assert not not_timing(after)  # the error reset cleared the flag


def test_a_sync_with_a_counter_the_nodes_do_not_expect_is_answered_with_emcy(robot, channel):
    """A second master sends SYNC with a counter byte: the nodes (0x1019 = 0) answer EMCY 0x8240;
    the sets are flagged with what to do, and clear once SYNCs match again."""
    cfg = config(channel)
    with MockEncoderNodes(robot, cfg), LegEncoders(cfg) as drv:
        [drv.read_set(1.0) for _ in range(5)]
        other = can.Bus(interface="virtual", channel=channel)
        other.send(can.Message(arbitration_id=0x080, data=[7], is_extended_id=False))
        other.shutdown()
        sets = [drv.read_set(1.0) for _ in range(20)]
    faults = [f for s in sets for f in s.faults]
    assert any(
        "EMCY 0x8240 (unexpected SYNC data length)" in f and "sync_counter" in f for f in faults
    )
    assert not not_timing(sets[-5:])  # the reset EMCY came with the next empty SYNC


def test_a_device_that_is_not_a_406_encoder_is_refused(robot, channel):
    cfg = config(channel)
    with MockEncoderNodes(robot, cfg, device_types={4: 0x00020192}):
        with pytest.raises(
            EncoderError,
            match=r"leg 4 encoder \(node 0x24\) .* is not a CiA 406 encoder: its device type "
            r"\(0x1000\) is 0x00020192, profile 402",
        ):
            LegEncoders(cfg).start()


def test_an_sdo_abort_names_the_object_and_the_code(robot, channel):
    cfg = config(channel)
    with MockEncoderNodes(robot, cfg, sdo_aborts={2: (0x1017, 0x06010002)}):
        with pytest.raises(
            EncoderError,
            match=r"leg 2 encoder \(node 0x22\) .*: SDO write of 125 to 0x1017:00 \(producer "
            r"heartbeat time\) aborted by the node: SDO abort 0x06010002 \(attempt to write a read "
            r"only object\) — it is read-only on this device",
        ):
            LegEncoders(cfg).start()


def test_a_node_that_does_not_answer_sdo_is_named(robot, channel):
    cfg = config(channel, sdo_timeout_s=0.1)
    with MockEncoderNodes(robot, cfg, sdo_deaf=[6]):
        with pytest.raises(
            EncoderSilent, match=r"leg 6 encoder \(node 0x26\) .*no SDO answer"
        ) as e:
            LegEncoders(cfg).start()
    assert e.value.legs == (6,) and e.value.node_ids == (0x26,)


def test_a_rebooted_node_is_set_up_again(robot, channel):
    """A reboot puts a node back at its factory settings (no heartbeat, TPDO1 cyclic): the
    driver sets it up again on its boot-up message, and the sets are complete again."""
    cfg = config(channel)
    with MockEncoderNodes(robot, cfg) as nodes, LegEncoders(cfg) as drv:
        [drv.read_set(1.0) for _ in range(5)]
        nodes.reboot(2)
        sets = [drv.read_set(1.0) for _ in range(60)]
        assert nodes.encoders[2].value(0x1017) == 125
    assert any("rebooted" in f for s in sets for f in s.faults)
    assert not not_timing(sets[-20:]) and sum(s.complete for s in sets[-20:]) >= 16


def test_emcy_text():
    assert emcy_text(0x8240) == "unexpected SYNC data length"
    assert emcy_text(0x4210) == "device temperature (0x4210)"
    assert emcy_text(0xFF07) == "device specific (0xFF07)"
    em = Emergency.from_frame(0x23, bytes([0x00, 0x00, 0x00]))
    assert em.is_reset


# -- LSS ----------------------------------------------------------------------------------------
def test_can_setup_gives_an_encoder_out_of_its_box_its_node_id(robot, channel, tmp_path, capsys):
    """Leg 3's encoder left the factory at node 1: the driver cannot find 0x23; `hexcal devices
    can-setup --serial` sets its id over LSS, and the rig starts."""
    cfg = config(channel)
    rig = tmp_path / "rig.toml"
    rig.write_text(
        '[tracker]\nurl = "loop://"\n\n[can]\ninterface = "virtual"\n'
        f'channel = "{channel}"\n'
        + "".join(
            f"[[can.legs]]\nleg = {k}\nnode_id = {0x20 + k}\ncounts_per_mm = 1000.0\n"
            for k in range(1, 7)
        )
    )
    with MockEncoderNodes(robot, cfg, factory_node_ids={3: 0x01}) as nodes:
        with pytest.raises(EncoderSilent) as exc:
            LegEncoders(cfg.model_copy(update={"sdo_timeout_s": 0.1})).start()
        assert exc.value.legs == (3,)
        args = ["devices", "can-setup", "--config", str(rig), "--serial", "4060003"]
        assert main([*args, "--node-id", "0x23"]) == 0
        assert "node id 0x01 → 0x23; stored" in capsys.readouterr().out
        assert nodes.encoders[3].node_id == 0x23
        with LegEncoders(cfg) as drv:
            sets = [drv.read_set(1.0) for _ in range(20)]
        assert sum(s.complete for s in sets) >= 16 and not not_timing(sets)
        # Nobody at that address: said so, exit 1.
        assert main([*args[:-1], "999", "--node-id", "0x23"]) == 1
        assert "no device answered LSS address" in capsys.readouterr().err


# -- a CANopen slave hexcal did not write ---------------------------------------------------------
VENDOR_EDS_CHANGES = {
    # A multi-turn rotary encoder whose position is UNSIGNED32 and wraps at 2**20 counts.
    "[6004]\nParameterName=Position value\nObjectType=0x7\nDataType=0x0004": (
        "[6004]\nParameterName=Position value\nObjectType=0x7\nDataType=0x0007"
    ),
    "ParameterName=Total measuring range in measuring units\nObjectType=0x7\nDataType=0x0007\n"
    "AccessType=rw\nDefaultValue=0": (
        "ParameterName=Total measuring range in measuring units\nObjectType=0x7\n"
        "DataType=0x0007\nAccessType=rw\nDefaultValue=1048576"
    ),
    "DefaultValue=0x00080196": "DefaultValue=0x00020196",
    "ParameterName=Vendor-ID\nObjectType=0x7\nDataType=0x0007\nAccessType=ro\n"
    "DefaultValue=0x00000000": "ParameterName=Vendor-ID\nObjectType=0x7\nDataType=0x0007\n"
    "AccessType=ro\nDefaultValue=0x0000012A",
}
WRAP = 2**20


def vendor_eds(tmp_path: Path) -> Path:
    text = generic_eds().read_text()
    for old, new in VENDOR_EDS_CHANGES.items():
        assert old in text, old
        text = text.replace(old, new)
    path = tmp_path / "vendor_406.eds"
    path.write_text(text)
    return path


class ForeignEncoder:
    """A CiA 406 slave built from canopen's LocalNode alone: canopen's NMT slave, heartbeat
    producer and SDO server, the EDS's factory values. canopen's LocalNode does not answer SYNC
    with its synchronous TPDOs, so that (and only that) is written here: on each SYNC, while
    OPERATIONAL, each valid TPDO with transmission type 1 sends 0x6004 as its EDS types it.
    The position moves ``step`` counts per SYNC from ``start``, modulo the range 2**20."""

    def __init__(self, net: canopen.Network, node_id: int, eds: Path, start: int, step: int):
        self.net, self.position, self.step = net, start, step
        self.node = canopen.LocalNode(node_id, str(eds))
        self.node.add_read_callback(self._read)
        net.add_node(self.node)
        net.subscribe(0x080, self._on_sync)
        self.node.nmt.send_command(0x81)  # boot-up
        self.node.nmt.send_command(0x80)  # pre-operational, heartbeat per 0x1017 (0: none)

    def counts(self) -> int:
        return self.position % WRAP

    def _read(self, index, subindex, od):
        return self.counts() if index == 0x6004 else None

    def _on_sync(self, can_id, data, timestamp):
        if self.node.nmt.state != "OPERATIONAL":
            return
        self.position += self.step  # the leg moves between SYNCs
        for n in range(4):
            cob = self.node.sdo[0x1800 + n][1].raw
            if cob & 0x80000000 or self.node.sdo[0x1800 + n][2].raw != 1:
                continue
            payload = self.node.object_dictionary[0x6004].encode_raw(self.counts())
            self.net.send_message(cob & 0x7FF, payload)


@pytest.fixture
def foreign(tmp_path, channel):
    """Six foreign encoders counting up through their wrap point (2**20), 500 counts per SYNC
    (50 mm/s at 100 Hz), from 20,000 counts below it (less 1000 per leg)."""
    eds = vendor_eds(tmp_path)
    net = canopen.Network()
    net.connect(interface="virtual", channel=channel)
    nodes = [ForeignEncoder(net, 0x20 + k, eds, WRAP - 20_000 + 1000 * k, 500) for k in range(1, 7)]
    yield eds, nodes
    for n in nodes:
        n.node.nmt.stop_heartbeat()
    net.disconnect()


def test_devices_check_configures_a_foreign_slave_and_reads_positions(
    foreign, channel, tmp_path, capsys
):
    from hexcal.mock_hw.ndi_registry import register_robot, unregister

    eds, nodes = foreign
    name = f"foreign{uuid.uuid4().hex[:6]}"
    register_robot(name, MockRobot(left_hand(), noise=DEFAULT_NOISE, seed=1), seed=1)
    rig = tmp_path / "rig.toml"
    rig.write_text(
        f'[tracker]\nurl = "ndimock://{name}"\nreset = "command"\n\n'
        f'[can]\ninterface = "virtual"\nchannel = "{channel}"\neds = "{eds.name}"\n'
        + "".join(
            f"[[can.legs]]\nleg = {k}\nnode_id = {0x20 + k}\ncounts_per_mm = 1000.0\n"
            for k in range(1, 7)
        )
    )
    try:
        assert main(["devices", "check", "--config", str(rig)]) == 0
    finally:
        unregister(name)
    out = capsys.readouterr().out
    assert out.count("multi-turn absolute rotary encoder (device type 0x00020196)") == 6
    assert out.count("vendor 0x0000012A") == 6
    assert out.count("position 0x6004 UNSIGNED32 in TPDO2") == 6
    assert out.count(f"wraps at {WRAP} counts (0x6002)") == 6
    assert "of 50 reading sets complete" in out and "all devices answer" in out
    assert all(n.node.sdo[0x1017].raw == 125 for n in nodes)  # 0.5 s / 4


def test_a_foreign_slaves_wrapping_position_is_unwrapped_and_its_emcy_flags_the_set(
    foreign, channel
):
    eds, nodes = foreign
    cfg = config(channel, eds=str(eds))
    with LegEncoders(cfg) as drv:
        sets = [drv.read_set(1.0) for _ in range(60)]  # 0.6 s: every leg crosses 2**20
        nodes[2].node.emcy.send(0x4210, 0x09)
        flagged = [drv.read_set(1.0) for _ in range(5)]
    done = [s for s in sets if s.complete]
    readings = np.array([s.readings_mm for s in done])
    assert len(readings) >= 45 and not not_timing(sets)
    per_sync = np.diff(readings, axis=0) / np.diff([s.index for s in done])[:, None]
    # Exactly 0.5 mm per SYNC on every leg, across the wrap too (never the 1048.576 mm of one).
    np.testing.assert_allclose(per_sync, 0.5, atol=1e-9)
    assert (readings[-1] - readings[0] > 20.0).all()
    assert readings[0, 0] > 1000.0 and readings[-1, 0] > WRAP / 1000  # continued past the wrap
    faults = [f for s in flagged for f in s.faults]
    assert any(
        "leg 3 encoder (node 0x23) sent EMCY 0x4210 (device temperature (0x4210))" in f
        for f in faults
    )
    assert threading.active_count() < 50
