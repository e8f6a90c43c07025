"""One mock CiA 406 encoder node of :class:`~hexcal.mock_hw.can_encoders.MockEncoderNodes`:
its ``canopen.LocalNode`` built from an EDS, the rules its object dictionary keeps (what may be
written in which NMT state, what may be mapped, a device whose TPDOs refuse RTR), its factory
reset and the node id LSS gives it; with the NMT, SDO, EMCY and LSS codes the mock speaks and
the canopen network glue that routes what a node sends through the mock."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Protocol

import can
import canopen
from canopen.objectdictionary import ODVariable
from canopen.sdo import SdoAbortedError

from hexcal.drivers.can_config import CanBusConfig
from hexcal.mock_hw.robot import MockRobot


class NodeHost(Protocol):
    """What a node asks of the mock that holds it: the bus configuration and the robot, the
    faults injected at construction, the counts a reading makes, and the way out to the bus."""

    config: CanBusConfig
    robot: MockRobot
    _sdo_deaf: Any
    _device_types: dict[int, int]
    _sdo_aborts: dict[int, tuple[int, int]]

    def _counts(self, enc: Encoder, reading_mm: float) -> int | float: ...

    def _send(self, msg: can.Message) -> None: ...

    def _periodic(self, can_id: int, data: bytes, period: float) -> Any: ...


BOOTUP, STOPPED, OPERATIONAL, PRE_OPERATIONAL = 0x00, 0x04, 0x05, 0x7F
_STATE_CODES = {"INITIALISING": BOOTUP, "STOPPED": STOPPED, "OPERATIONAL": OPERATIONAL}
_NMT_RESETS = (0x81, 0x82)

# SocketCAN error classes the emulated faults use (linux/can/error.h).
CAN_ERR_PROT = 0x008
CAN_ERR_BUSOFF = 0x040
CAN_ERR_BUSERROR = 0x080
CAN_ERR_RESTARTED = 0x100

#: SDO abort codes (CiA 301 table 22) the nodes answer with.
ABORT_DEVICE_STATE = 0x08000022
ABORT_NOT_MAPPABLE = 0x06040041
ABORT_VALUE_RANGE = 0x06090030
#: A TPDO COB-ID's bit 30: no remote transmission request (RTR) for this PDO.
RTR_NOT_ALLOWED = 0x40000000
#: CiA 301 "store EDS": the device's own EDS, read by SDO.
STORE_EDS = 0x1021
#: EMCY: unexpected SYNC data length; error register bits 0 (generic) and 4 (communication).
EMCY_SYNC_LENGTH = 0x8240
REGISTER_COMMUNICATION = 0x11

LSS_MASTER_COB_ID, LSS_SLAVE_COB_ID = 0x7E5, 0x7E4
#: LSS bit-timing table index → bit/s (CiA 305).
LSS_BIT_TIMING = {
    0: 1_000_000,
    1: 800_000,
    2: 500_000,
    3: 250_000,
    4: 125_000,
    6: 50_000,
    7: 20_000,
    8: 10_000,
}


def _position_variable(node: canopen.LocalNode) -> ODVariable:
    """0x6004 (position value) in the node's object dictionary, a single variable in any
    CiA 406 EDS."""
    od = node.object_dictionary[0x6004]
    if not isinstance(od, ODVariable):
        raise TypeError(f"0x6004 in the EDS is a {type(od).__name__}, not a single variable")
    return od


class NodeNetwork(canopen.Network):
    """The mock's side of the bus: every frame a node sends goes through the mock's
    ``_send`` (stamping, silence, bus-off), and periodic frames (the
    heartbeat) are scheduled by the mock's thread rather than the interface's own timer."""

    def __init__(self, owner: NodeHost, bus: can.BusABC):
        super().__init__(bus)
        self.owner = owner

    def send_message(self, can_id: int, data: Any, remote: bool = False) -> None:
        self.owner._send(can.Message(arbitration_id=can_id, data=bytes(data), is_extended_id=False))

    def send_periodic(self, can_id: int, data: Any, period: float, remote: bool = False) -> Any:
        return self.owner._periodic(can_id, bytes(data), period)


class Periodic:
    """A periodic frame of the mock's scheduler (the heartbeat): canopen's task interface."""

    def __init__(self, owner: NodeHost, can_id: int, data: bytes, period: float):
        self.owner, self.can_id, self.data, self.period = owner, can_id, data, period
        self.next = time.monotonic() + period
        self.stopped = False

    def update(self, data: Any) -> None:
        self.data = bytes(data)

    def stop(self) -> None:
        self.stopped = True


class Encoder:
    """One encoder: its LocalNode, the node id it answers at, and its LSS state."""

    def __init__(self, owner: NodeHost, leg: int, node_id: int, eds: str, serial: int):
        self.owner, self.leg, self.eds, self.serial = owner, leg, eds, serial
        self.node_id = node_id
        self.pending_id = node_id  # set by LSS, in effect after an NMT reset
        self.bitrate = owner.config.bitrate
        self.lss_config = False  # LSS configuration state
        self.lss_selective: list[int] = []
        self.sync_error = False  # EMCY 0x8240 sent, no reset yet
        self.sync_count = [0] * 5  # SYNCs since the last transmission, per TPDO 1..4
        self.next_cyclic = [0.0] * 5
        self.node = self._build()

    def _build(self) -> canopen.LocalNode:
        node = canopen.LocalNode(self.node_id, canopen.import_od(self.eds, self.node_id))
        node.add_read_callback(self._on_read)
        node.add_write_callback(self._on_write)
        node.data_store.setdefault(0x1018, {})[4] = self.serial.to_bytes(4, "little")
        return node

    def attach(self, network: NodeNetwork) -> None:
        self.node.associate_network(network)
        # NMT is the mock's (boot-up on reset, silence, factory reset); not the LocalNode's.
        network.unsubscribe(0, self.node.nmt.on_command)
        if self.leg in self.owner._sdo_deaf:
            network.unsubscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)

    def detach(self) -> None:
        self.node.nmt.stop_heartbeat()
        # remove_network() unsubscribes what associate_network() subscribed: put back what
        # attach() took away first.
        network = self.node.network
        network.subscribe(0, self.node.nmt.on_command)
        if self.leg in self.owner._sdo_deaf:
            network.subscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)
        self.node.remove_network()

    # -- object dictionary rules ---------------------------------------------------------------
    @property
    def state(self) -> int:
        return _STATE_CODES.get(self.node.nmt.state, PRE_OPERATIONAL)

    def has(self, index: int, sub: int = 0) -> bool:
        """Whether this node's object dictionary (its EDS) holds ``index``:``sub``."""
        od = self.node.object_dictionary
        if index not in od:
            return False
        obj = od[index]
        return isinstance(obj, ODVariable) or sub in obj

    def value(self, index: int, sub: int = 0, default: int | None = None) -> int:
        """An object's value as the node holds it (written, else the EDS default), without the
        SDO server's callbacks (the faults injected there are for the master's requests).
        ``default``: the value of an object this node's EDS does not hold (KeyError without)."""
        if default is not None and not self.has(index, sub):
            return default
        obj = self.node.object_dictionary[index]
        var = obj if isinstance(obj, ODVariable) else obj[sub]
        raw = self.node.data_store.get(index, {}).get(sub)
        if raw is None:
            return int(var.value if var.value is not None else (var.default or 0))
        return int(var.decode_raw(raw))

    def _on_read(self, index: int, subindex: int, od: ODVariable) -> Any:
        if index == STORE_EDS:  # the device keeps its own EDS (CiA 301 0x1021, a DOMAIN)
            return Path(self.eds).read_bytes()
        if index == 0x1000 and self.leg in self.owner._device_types:
            return self.owner._device_types[self.leg]
        if index == 0x6004:
            return self.owner._counts(
                self, float(self.owner.robot.encoder_readings()[self.leg - 1])
            )
        return None

    def _on_write(self, index: int, subindex: int, od: ODVariable, data: bytes) -> None:
        abort = self.owner._sdo_aborts.get(self.leg)
        if abort is not None and abort[0] == index:
            raise SdoAbortedError(abort[1])
        pdo_object = 0x1800 <= index <= 0x1803 or 0x1A00 <= index <= 0x1A03
        if (pdo_object or index == 0x1019) and self.state != PRE_OPERATIONAL:
            raise SdoAbortedError(ABORT_DEVICE_STATE)
        if 0x1800 <= index <= 0x1803 and subindex == 1:
            value = int.from_bytes(data, "little")
            factory = int(od.default or 0)  # the COB-ID this device left the factory with
            if factory & RTR_NOT_ALLOWED and not value & RTR_NOT_ALLOWED:
                # A device whose TPDOs cannot be requested by RTR (bit 30 set at the factory)
                # refuses a COB-ID that asks for it, as CiA 301 lets it.
                raise SdoAbortedError(ABORT_VALUE_RANGE)
        if 0x1A00 <= index <= 0x1A03 and subindex > 0:
            valid = not self.value(0x1800 + index - 0x1A00, 1) & 0x80000000
            if valid or self.value(index, 0) != 0:
                raise SdoAbortedError(ABORT_DEVICE_STATE)
            entry = int.from_bytes(data, "little")
            target, sub = entry >> 16, (entry >> 8) & 0xFF
            if entry and not self._mappable(target, sub):
                raise SdoAbortedError(ABORT_NOT_MAPPABLE)

    def _mappable(self, index: int, sub: int) -> bool:
        od = self.node.object_dictionary
        if index not in od:
            return False
        obj = od[index]
        var = obj if isinstance(obj, ODVariable) else obj.get(sub)
        return bool(var is not None and var.pdo_mappable)

    def factory_reset(self, communication_only: bool) -> None:
        """NMT reset: objects back to their factory values (the EDS's defaults); a node id set
        by LSS takes effect."""
        store = self.node.data_store
        for index in list(store):
            if not communication_only or 0x1000 <= index <= 0x1FFF:
                del store[index]
        store.setdefault(0x1018, {})[4] = self.serial.to_bytes(4, "little")
        self.sync_error = False
        if self.pending_id != self.node_id:
            network = self.node.network
            if not isinstance(network, NodeNetwork):
                raise RuntimeError(f"leg {self.leg}'s encoder is not on the mock's network")
            self.detach()
            self.node_id = self.pending_id
            self.node = self._build()
            self.attach(network)
