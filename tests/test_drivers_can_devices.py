"""The set-up against encoders hexcal did not write: canopen's own LocalNode (tests/can_slaves.py)
built from each of the three mock EDS files (mock_hw/eds: minimal, vendor-like, linear; written
from the CiA 301/406 object lists, not from hexcal's generic EDS), at their factory settings.
`hexcal devices check` must set six of them up and read 50 of 50 complete sets; the two-TPDO
device of issue 25 is reproduced; a missing mandatory object is refused by name; and every SDO
access the set-up makes, when refused, is named in the message exactly as it was made."""

from __future__ import annotations

import logging
import re
import uuid
from pathlib import Path

import canopen
import pytest
from can_slaves import ForeignEncoder, slave_network

from hexcal.app.cli import main
from hexcal.drivers.can_config import CanBusConfig, LegEncoderConfig
from hexcal.drivers.can_encoders import EncoderError, LegEncoders
from hexcal.drivers.can_nodes import EncoderConfigError, configure_node, generic_eds
from hexcal.mock_hw.eds_files import mock_eds
from hexcal.mock_hw.ndi_registry import register_robot, unregister
from hexcal.mock_hw.robot import DEFAULT_NOISE, MockRobot
from hexcal.sim.robots import left_hand

#: counts per mm of each device: 1 µm counts for the rotary ones (a leg's lead screw), the
#: linear sensor's own 5 µm step (0x6005 = 5000 nm).
CPM = {"minimal": 1000.0, "vendor": 1000.0, "linear": 200.0}


def counts(name: str, k: int) -> int:
    """Leg k's position (counts): 512.345 mm + k mm."""
    return round((512.345 + k) * CPM[name])


@pytest.fixture
def channel() -> str:
    return f"hexcal-devices-{uuid.uuid4().hex[:8]}-bus"


def slaves(channel: str, name: str, eds: Path | None = None, **kw):
    """Six ForeignEncoders from mock EDS ``name`` (or ``eds``) on ``channel``: (network, nodes)."""
    net = slave_network(channel)
    path = eds or mock_eds(name)
    nodes = [
        ForeignEncoder(net, 0x20 + k, path, lambda k=k: counts(name, k), **kw) for k in range(1, 7)
    ]
    return net, nodes


def close(net, nodes) -> None:
    for n in nodes:
        n.close()
    net.disconnect()


def rig_file(tmp_path: Path, channel: str, name: str, eds: str | None, tracker: str) -> Path:
    rig = tmp_path / "rig.toml"
    rig.write_text(
        f'[tracker]\nurl = "ndimock://{tracker}"\nreset = "command"\n\n'
        f'[can]\ninterface = "virtual"\nchannel = "{channel}"\n'
        + (f'eds = "{eds}"\n' if eds else "")
        + "".join(
            f"[[can.legs]]\nleg = {k}\nnode_id = {0x20 + k}\ncounts_per_mm = {CPM[name]}\n"
            for k in range(1, 7)
        )
    )
    return rig


# name, whether the rig file names the EDS, what `devices check` must say of each node
CASES = [
    (
        "minimal",
        False,
        [
            "multi-turn absolute rotary encoder (device type 0x00020196); vendor 0x00000F01, "
            "product ?, revision ?, serial ?",
            "has: TPDOs 1, 2 (sub-indices 0..2); no SYNC counter 0x1019",
            "absent (optional, skipped): 0x1018:02 (identity, product code), 0x1018:03 "
            "(identity, revision), 0x1018:04 (identity, serial number), 0x1021:00 (store EDS), "
            "0x1802:00 (TPDO3 highest sub-index), 0x1803:00 (TPDO4 highest sub-index), 0x1019:00 (SYNC "
            "counter overflow), 0x6002:00 (total measuring range), 0x6003:00 (preset value)",
            "in TPDO2 (COB-ID 0x2A{k}) on every SYNC (its fixed mapping kept); TPDO 1 disabled; "
            "heartbeat every 125 ms; SYNC without counter",
            "(hexcal generic)",
        ],
    ),
    (
        "minimal",
        True,
        ["position 0x6004 UNSIGNED32 in TPDO2", "minimal_406.eds (rig file)"],
    ),
    (
        "vendor",
        False,
        [
            "has: TPDOs 1, 2, 3, 4 (sub-indices 0..6); SYNC counter 0x1019; position 0x6004 "
            "INTEGER32; wraps at 33554432 counts (0x6002); 7 manufacturer objects (0x2000..0x5FFF)",
            "TPDO 1 disabled",
            "(stored in the device (0x1021))",
        ],
    ),
    (
        "linear",
        False,
        [
            "absolute linear encoder (device type 0x00080196); vendor 0x00000F03, product "
            "0x00000E05",
            "has: TPDOs 1, 2, 3, 4 (sub-indices 0..5); no SYNC counter 0x1019",
            "absent (optional, skipped): 0x1021:00 (store EDS), 0x1019:00 (SYNC counter "
            "overflow), 0x6003:00 (preset value)",
            "step 5000 nm per count (0x6005)",
        ],
    ),
]


@pytest.mark.parametrize(
    "name, in_rig, said", CASES, ids=["minimal", "minimal-eds-in-rig", "vendor", "linear"]
)
def test_devices_check_sets_up_six_foreign_nodes_and_reads_50_of_50(
    name, in_rig, said, channel, tmp_path, capsys
):
    eds = mock_eds(name)
    net, nodes = slaves(channel, name, store_eds=name == "vendor")
    tracker = f"foreign{uuid.uuid4().hex[:6]}"
    register_robot(tracker, MockRobot(left_hand(), noise=DEFAULT_NOISE, seed=1), seed=1)
    try:
        rig = rig_file(tmp_path, channel, name, str(eds) if in_rig else None, tracker)
        code = main(["devices", "check", "--config", str(rig)])
        out = capsys.readouterr().out
        assert code == 0, out
        assert "50 of 50 reading sets complete" in out and "all devices answer" in out
        for k in range(1, 7):
            assert (
                f"(node 0x{0x20 + k:02X}): alive, OPERATIONAL, reading {512.345 + k:.4f} mm" in out
            )
        for text in said:
            for k in range(1, 7):
                assert out.count(text.format(k=k)) == (6 if "{k}" not in text else 1), (text, out)
        assert "NOTE" not in out and "ALARM" not in out
        for n in nodes:
            nid = n.node.id
            assert n.value(0x1017) == 125  # heartbeat_timeout_s 0.5 / 4
            assert n.value(0x1801, 2) == 1  # TPDO2 on every SYNC
            assert n.value(0x1800, 1) & 0x80000000  # TPDO1 (cyclic at the factory) disabled
            # The RTR bit as the device had it: the linear sensor's TPDOs refuse RTR (bit 30).
            rtr = 0x40000000 if name == "linear" else 0
            assert n.value(0x1801, 1) == 0x280 + nid + rtr
            # Objects the device lacks were only probed, never written or read past sub-index 0.
            od = n.node.object_dictionary
            for op, index, sub in n.accesses:
                if index not in od:
                    assert (op, sub) == ("read", 0), (op, hex(index), sub)
    finally:
        unregister(tracker)
        close(net, nodes)


def config(channel: str, name: str, **kw) -> CanBusConfig:
    legs = [LegEncoderConfig(leg=k, node_id=0x20 + k, counts_per_mm=CPM[name]) for k in range(1, 7)]
    base = {"sync_period_s": 0.01, "heartbeat_timeout_s": 0.5, "sdo_timeout_s": 0.3}
    return CanBusConfig(interface="virtual", channel=channel, legs=legs, **{**base, **kw})


def test_the_two_tpdo_device_of_issue_25(channel, caplog):
    """canopen's LocalNode at factory settings (TPDO1 asynchronous, TPDO2 on SYNC, heartbeat
    off, no SYNC counter, UNSIGNED32 position), two TPDOs, no sub-index 6, driven with hexcal's
    generic EDS (four TPDOs): the set-up used to read 0x1802:01 — TPDO3, which the device
    never had — and stop with a message naming 0x1801; no set was read. Now TPDO3 and TPDO4 are
    probed (sub-index 0), found absent, skipped and logged, and every set is complete."""
    net, nodes = slaves(channel, "minimal")
    try:
        caplog.set_level(logging.INFO, logger="hexcal.drivers.can_nodes")
        with LegEncoders(config(channel, "minimal")) as drv:
            sets = [drv.read_set(1.0) for _ in range(30)]
            infos = drv.nodes
    finally:
        close(net, nodes)
    timing = ("arrived", "sent no position", "outside any SYNC window")
    assert not [f for s in sets for f in s.faults if not any(w in f for w in timing)]
    assert sum(s.complete for s in sets) >= 28
    assert all(
        s.readings_mm[k] == pytest.approx(512.345 + k + 1)
        for s in sets
        if s.complete
        for k in range(6)
    )
    for info in infos:
        assert info.tpdos == (1, 2) and info.tpdo_highest == (2, 2) and info.static_mapping
        assert "0x1802:00 (TPDO3 highest sub-index)" in info.absent
    for n in nodes:
        touched = {(op, i, s) for op, i, s in n.accesses if i in (0x1802, 0x1803)}
        assert touched == {("read", 0x1802, 0), ("read", 0x1803, 0)}
    assert (
        "leg 1 encoder (node 0x21) has no 0x1802:00 (TPDO3 highest sub-index) (optional): skipped"
        in caplog.text
    )


def _strip(eds: Path, index: int, tmp_path: Path) -> Path:
    """``eds`` without object ``index`` (its sections and its line in the object lists)."""
    text = eds.read_text()
    text = re.sub(rf"\n\[{index:04X}(sub[0-9A-F]+)?\]\n(.+\n)+", "\n", text)
    text = re.sub(rf"\n\d+=0x{index:04X}\n", "\n", text)
    path = tmp_path / f"without_{index:04X}.eds"
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "missing, kw, said",
    [
        (
            0x6004,
            {},
            r"leg 1 encoder \(node 0x21\) on CAN virtual channel '[^']+' has no 0x6004:00 "
            r"\(position value\): hexcal reads the leg length from it .* — check that this is a "
            r"single-sensor CiA 406 encoder",
        ),
        (
            # canopen's LocalNode needs 0x1017 itself (its NMT slave reads it): the node keeps
            # it and answers the master "object does not exist", as a device without it does.
            "refuse 0x1017",
            {},
            r"has no 0x1017:00 \(producer heartbeat time\): hexcal supervises each encoder by its "
            r"heartbeat, and this one has none .* — use an encoder with a heartbeat producer",
        ),
        (
            None,
            {"tpdo": 3},
            r"has no 0x1802:00 \(TPDO3 highest sub-index\): the device has TPDO1, TPDO2 \(probed "
            r"0x1800..0x1803 sub-index 0\), not TPDO3 — set can.tpdo in the rig file to one it has",
        ),
        (
            0x1019,
            {"sync_counter": 240},
            r"has no 0x1019:00 \(SYNC counter overflow\): it cannot take a SYNC with a counter "
            r"\(the rig file's sync_counter = 240\) — set sync_counter = 0",
        ),
        (
            0x1000,
            {},
            r"has no 0x1000:00 \(device type\): every CANopen device has one \(CiA 301\) — is node "
            r"id 0x21 the encoder the rig file means\?",
        ),
    ],
    ids=["position", "heartbeat", "rig's TPDO", "SYNC counter", "device type"],
)
def test_a_missing_mandatory_object_is_refused_by_name(missing, kw, said, channel, tmp_path):
    strip = isinstance(missing, int)
    eds = _strip(mock_eds("minimal"), missing, tmp_path) if strip else mock_eds("minimal")
    net, nodes = slaves(channel, "minimal", eds=eds)
    if missing == "refuse 0x1017":
        for n in nodes:
            n.refuse = {(op, 0x1017, 0): 0x06020000 for op in ("read", "write")}
    try:
        with pytest.raises(EncoderError, match=said):
            LegEncoders(config(channel, "minimal", **kw)).start()
    finally:
        close(net, nodes)


@pytest.mark.parametrize("name", ["minimal", "vendor", "linear"])
def test_every_sdo_failure_names_the_object_accessed(name, channel):
    """Every SDO access the set-up makes (traced on the node), refused in turn with a code that
    is not "no such object": the message names that very object and sub-index, read or write,
    the abort code, and what to do."""
    eds = mock_eds(name)
    net, master = slave_network(channel), canopen.Network()  # the slave's side and hexcal's
    master.connect(interface="virtual", channel=channel)
    try:
        node = ForeignEncoder(net, 0x21, eds, lambda: 1000, store_eds=name == "vendor")
        cfg = config(channel, name, sdo_timeout_s=0.5)
        master.add_node(0x21, str(generic_eds()))
        configure_node(master, cfg.leg(1), cfg)
        made = list(dict.fromkeys(node.accesses))  # in order, once each
        assert ("write", 0x1801, 2) in made and ("write", 0x1017, 0) in made
        for op, index, sub in made:
            node.node.data_store.clear()  # back to the factory values
            if name == "vendor":
                node.node.data_store.setdefault(0x1021, {})[0] = eds.read_bytes()
            node.refuse = {(op, index, sub): 0x08000020}
            master[0x21].remove_network()
            master.add_node(0x21, str(generic_eds()))  # a fresh RemoteNode: the generic EDS again
            with pytest.raises(EncoderConfigError) as exc:
                configure_node(master, cfg.leg(1), cfg)
            text = str(exc.value)
            assert f"SDO {op} of " in text and f"0x{index:04X}:{sub:02X} (" in text, text
            assert "aborted by the node: SDO abort 0x08000020" in text, text
            assert text.startswith("leg 1 encoder (node 0x21) on CAN virtual channel"), text
            assert " — " in text  # followed by what to do
    finally:
        node.close()
        net.disconnect()
        master.disconnect()
