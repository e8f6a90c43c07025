"""What hexcal sets up on each CiA 406 encoder before it reads it, over SDO in PRE-OPERATIONAL.

A CiA 406 encoder out of its box does not send what hexcal reads: by the profile's convention
TPDO1 (0x180 + node) is asynchronous / cyclic (its period in 0x6200), **TPDO2 (0x280 + node)
is the synchronous one**; the heartbeat producer (0x1017) is 0 (off) or slow; the SYNC counter
overflow (0x1019) is 0, so a SYNC with a counter byte is a protocol error to it (EMCY 0x8240).
So, per node, :func:`configure_node`:

1. reads the device type 0x1000 and refuses anything whose profile is not 406, naming it;
2. reads the identity 0x1018 (vendor, product, revision, serial; logged and stored);
3. maps 0x6004 alone into the TPDO the rig file names (``tpdo``, default 2), transmission type
   1 (every SYNC), and disables the other TPDOs (or leaves them, ``other_tpdos = "keep"``) —
   through ``canopen``'s PDO maps, which write in the order CiA 301 requires (PDO invalid,
   mapping count 0, entries, count, PDO valid);
4. writes the heartbeat producer time hexcal supervises;
5. reads the SYNC counter overflow 0x1019 (or writes the rig file's value), so SYNC goes out with
   or without the counter as the devices expect;
6. reads what it needs to decode the position: the data type of 0x6004 (UNSIGNED32 on several
   encoders, INTEGER32 on others: from the object dictionary, the EDS's or the node's own), the
   total measuring range 0x6002 (the position wraps there), and reports the operating
   parameters 0x6000 (code sequence), the preset 0x6003 and the linear measuring step 0x6005.

Objects a node does not have (an SDO abort "object does not exist") are optional except
0x1000 and 0x6004; every other abort, and a node that does not answer SDO at all, is an
:class:`EncoderConfigError` naming the leg, the node, the object and what to do.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import canopen
from canopen.objectdictionary import SIGNED_TYPES, ODVariable
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from hexcal.drivers.can_config import CanBusConfig, LegEncoderConfig
from hexcal.errors import DeviceError

log = logging.getLogger(__name__)

#: CiA 406's profile number, the low 16 bits of object 0x1000.
CIA406 = 0x0196
#: Encoder types in the high 16 bits of 0x1000 (CiA 406; as vendor manuals list them).
ENCODER_TYPES = {
    0x0001: "single-turn absolute rotary encoder",
    0x0002: "multi-turn absolute rotary encoder",
    0x0008: "absolute linear encoder",
    0x000A: "absolute linear encoder, multi-sensor",
}
#: CiA 301 object-dictionary indices used here.
DEVICE_TYPE, IDENTITY, HEARTBEAT_PRODUCER, SYNC_OVERFLOW = 0x1000, 0x1018, 0x1017, 0x1019
OPERATING_PARAMETERS, TOTAL_RANGE, PRESET, POSITION, LINEAR_STEP = (
    0x6000,
    0x6002,
    0x6003,
    0x6004,
    0x6005,
)
#: SDO abort codes that mean "this node has no such object" (CiA 301 table 22).
NO_OBJECT = (0x06020000, 0x06090011)
#: The SYNC counter overflow values CiA 301 allows: 0 (no counter) or 2..240.
SYNC_OVERFLOW_VALUES = (0, *range(2, 241))


def generic_eds() -> Path:
    """The CiA 406 EDS shipped with hexcal (a generic absolute linear encoder)."""
    with resources.as_file(resources.files("hexcal").joinpath("data/cia406_encoder.eds")) as p:
        return Path(p)


def eds_for(bus: CanBusConfig, leg: LegEncoderConfig) -> Path:
    """The EDS leg ``leg``'s node is described by: its own, the bus's, else hexcal's generic."""
    path = leg.eds or bus.eds
    return Path(path) if path else generic_eds()


class EncoderConfigError(DeviceError):
    """An encoder could not be set up; the message names the leg, the node, the object and
    what to do."""

    def __init__(self, message: str, leg: int = 0, node_id: int = 0, silent: bool = False):
        super().__init__(message)
        self.leg = leg
        self.node_id = node_id
        #: The node did not answer at all (no SDO response), rather than refusing.
        self.silent = silent


@dataclass(frozen=True)
class NodeInfo:
    """What the configuration step read from (and set on) one encoder."""

    leg: int
    node_id: int
    device_type: int
    vendor_id: int | None
    product_code: int | None
    revision: int | None
    serial: int | None
    #: "INTEGER32" or "UNSIGNED32": how 0x6004 is decoded.
    position_type: str
    #: 0x6002 in counts; None (or 0) when the node has none: no wrap-around.
    total_range: int | None
    operating_parameters: int | None
    preset: int | None
    #: 0x6005 sub 1, nm per count (linear encoders); None when absent.
    step_nm: int | None
    tpdo: int
    tpdo_cob_id: int
    heartbeat_ms: int
    sync_overflow: int
    eds: str

    @property
    def encoder_type(self) -> str:
        kind = self.device_type >> 16
        return ENCODER_TYPES.get(kind, f"encoder type 0x{kind:04X}")

    @property
    def identity(self) -> str:
        def h(v: int | None) -> str:
            return "?" if v is None else f"0x{v:08X}"

        return (
            f"vendor {h(self.vendor_id)}, product {h(self.product_code)}, "
            f"revision {h(self.revision)}, serial {self.serial if self.serial is not None else '?'}"
        )

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "encoder_type": self.encoder_type}


def _name(leg: LegEncoderConfig) -> str:
    return leg.name


class _Sdo:
    """SDO access to one node with the errors hexcal gives."""

    def __init__(self, node: canopen.RemoteNode, leg: LegEncoderConfig, bus: CanBusConfig):
        self.node, self.leg, self.bus = node, leg, bus

    def _fail(self, what: str, index: int, sub: int | None, exc: Exception) -> EncoderConfigError:
        where = f"0x{index:04X}" + (f" sub {sub}" if sub is not None else "")
        if isinstance(exc, SdoAbortedError):
            why = f"SDO abort 0x{exc.code:08X} ({exc})"
            todo = (
                "the node refuses this setting — check the EDS matches the device (can.eds in "
                "the rig file), or set the object by the vendor's tool"
            )
        else:
            why = f"no SDO answer ({exc})"
            todo = (
                f"check that it is powered, wired to this bus, has node id 0x{self.leg.node_id:02X} "
                f"and runs at {self.bus.bitrate // 1000} kbit/s (`hexcal devices can-setup` sets "
                "node id and bit rate over LSS)"
            )
        return EncoderConfigError(
            f"{_name(self.leg)} on {self.bus.bus_name}: {what} {where}: {why} — {todo}",
            self.leg.leg,
            self.leg.node_id,
            silent=not isinstance(exc, SdoAbortedError),
        )

    def read(self, index: int, sub: int | None = None, *, optional: bool = False) -> int | None:
        what = "reading"
        try:
            var = self.node.sdo[index] if sub is None else self.node.sdo[index][sub]
            return int(var.raw)
        except SdoAbortedError as exc:
            if optional and exc.code in NO_OBJECT:
                return None
            raise self._fail(what, index, sub, exc) from None
        except KeyError:  # not in the object dictionary (EDS) at all
            if optional:
                return None
            raise EncoderConfigError(
                f"{_name(self.leg)}: object 0x{index:04X} is not in its EDS — give the vendor's "
                "EDS (can.eds in the rig file)",
                self.leg.leg,
                self.leg.node_id,
            ) from None
        except SdoCommunicationError as exc:
            raise self._fail(what, index, sub, exc) from None

    def write(self, index: int, sub: int | None, value: int) -> None:
        try:
            var = self.node.sdo[index] if sub is None else self.node.sdo[index][sub]
            var.raw = value
        except (SdoAbortedError, SdoCommunicationError) as exc:
            raise self._fail(f"writing {value} to", index, sub, exc) from None


def configure_node(network: canopen.Network, leg: LegEncoderConfig, bus: CanBusConfig) -> NodeInfo:
    """Set up leg ``leg``'s encoder (steps in the module docstring); the node must be in
    PRE-OPERATIONAL (it may be OPERATIONAL for the reads, not for the PDO writes). Returns what
    was read and set; raises :class:`EncoderConfigError`."""
    node = network[leg.node_id]
    if not isinstance(node, canopen.RemoteNode):
        raise EncoderConfigError(
            f"{_name(leg)}: node id 0x{leg.node_id:02X} on {bus.bus_name} is served by this host "
            "(a canopen LocalNode), not an encoder it can configure",
            leg.leg,
            leg.node_id,
        )
    node.sdo.RESPONSE_TIMEOUT = bus.sdo_timeout_s
    sdo = _Sdo(node, leg, bus)
    device_type = sdo.read(DEVICE_TYPE)
    assert device_type is not None
    if device_type & 0xFFFF != CIA406:
        raise EncoderConfigError(
            f"{_name(leg)} on {bus.bus_name} is not a CiA 406 encoder: its device type (0x1000) "
            f"is 0x{device_type:08X}, profile {device_type & 0xFFFF} — is node id "
            f"0x{leg.node_id:02X} another device? Fix the node id in the rig file or the device",
            leg.leg,
            leg.node_id,
        )
    ident = [sdo.read(IDENTITY, s, optional=True) for s in (1, 2, 3, 4)]
    od_pos = node.object_dictionary[POSITION]
    if not isinstance(od_pos, ODVariable):
        raise EncoderConfigError(
            f"{_name(leg)}: 0x{POSITION:04X} (position value) is not a single variable in its EDS "
            "— give the vendor's EDS (can.eds in the rig file)",
            leg.leg,
            leg.node_id,
        )
    position_type = "INTEGER32" if od_pos.data_type in SIGNED_TYPES else "UNSIGNED32"
    total_range = sdo.read(TOTAL_RANGE, optional=True) or None
    operating = sdo.read(OPERATING_PARAMETERS, optional=True)
    preset = sdo.read(PRESET, optional=True)
    step_nm = (
        sdo.read(LINEAR_STEP, 1, optional=True) if LINEAR_STEP in node.object_dictionary else None
    )

    if bus.sync_counter is None:
        overflow = sdo.read(SYNC_OVERFLOW, optional=True) or 0
    else:
        overflow = bus.sync_counter
        sdo.write(SYNC_OVERFLOW, None, overflow)

    heartbeat_ms = bus.heartbeat_period_ms
    sdo.write(HEARTBEAT_PRODUCER, None, heartbeat_ms)

    try:
        _map_position(node, bus)
    except (SdoAbortedError, SdoCommunicationError) as exc:
        where = 0x1800 + bus.tpdo - 1
        raise sdo._fail(f"mapping 0x6004 into TPDO{bus.tpdo} at", where, None, exc) from None
    info = NodeInfo(
        leg=leg.leg,
        node_id=leg.node_id,
        device_type=device_type,
        vendor_id=ident[0],
        product_code=ident[1],
        revision=ident[2],
        serial=ident[3],
        position_type=position_type,
        total_range=total_range,
        operating_parameters=operating,
        preset=preset,
        step_nm=step_nm,
        tpdo=bus.tpdo,
        tpdo_cob_id=leg.tpdo_cob_id(bus.tpdo),
        heartbeat_ms=heartbeat_ms,
        sync_overflow=overflow,
        eds=str(eds_for(bus, leg)),
    )
    log.info(
        "%s: %s, %s, TPDO%d on every SYNC", _name(leg), info.encoder_type, info.identity, bus.tpdo
    )
    return info


def _map_position(node: canopen.RemoteNode, bus: CanBusConfig) -> None:
    """0x6004 alone in TPDO ``bus.tpdo``, on every SYNC; the other TPDOs disabled unless kept."""
    for n in (1, 2, 3, 4):
        if 0x1800 + n - 1 not in node.object_dictionary:
            continue
        pdo = node.tpdo[n]
        if n == bus.tpdo:
            pdo.clear()
            pdo.add_variable(POSITION)
            pdo.trans_type = 1
            pdo.cob_id = pdo.predefined_cob_id
            pdo.enabled = True
            pdo.save()
        elif bus.other_tpdos == "disable":
            cob = pdo.com_record[1]
            value = int(cob.raw)
            if not value & 0x80000000:
                cob.raw = value | 0x80000000


__all__ = [
    "CIA406",
    "ENCODER_TYPES",
    "EncoderConfigError",
    "NodeInfo",
    "configure_node",
    "eds_for",
    "generic_eds",
]
