"""What hexcal sets up on each CiA 406 encoder before it reads it, over SDO in PRE-OPERATIONAL
— asking the device what it has rather than assuming what an EDS lists.

A CiA 406 encoder out of its box does not send what hexcal reads: by the profile's convention
TPDO1 (0x180 + node) is asynchronous / cyclic, **TPDO2 (0x280 + node) is the synchronous
one**; the heartbeat producer (0x1017) is 0 (off) or slow; the SYNC counter overflow (0x1019)
is 0, so a SYNC with a counter byte is a protocol error to it (EMCY 0x8240). And devices differ
in what they implement: two TPDOs or four, communication records with or without sub-indices
3, 5 and 6, fixed (read-only) PDO mappings, 0x1019 or not, 0x6005 or not, an EDS stored in the
device (0x1021), manufacturer areas. So, per node, :func:`configure_node`:

1. reads the device type 0x1000 and refuses anything whose profile is not 406, naming it;
2. takes its object dictionary from the rig file's EDS (``can.eds`` / ``can.legs[].eds``) if it
   names one, else from the EDS the device stores at 0x1021 (storage format 0x1022 = 0, plain
   text), else hexcal's generic CiA 406 EDS — which only types the position (INTEGER32);
   everything else is asked of the device;
3. reads the identity 0x1018 (sub-indices 1..4, each optional; before step 2, which reads a
   stored EDS once per kind of device: vendor, product and revision);
4. probes each TPDO communication record's sub-index 0 (0x1800..0x1803: which TPDOs exist, and
   their highest sub-index), then maps 0x6004 alone into the TPDO the rig file names (``tpdo``,
   default 2), transmission type 1 (every SYNC), in the order CiA 301 requires (PDO invalid,
   mapping count 0, the entry, count 1, PDO valid again with its RTR bit 30 as the device had
   it) — or, where the device's mapping is fixed (the count is read-only), checks that it starts
   with 0x6004 — and disables the other TPDOs it has (or leaves them, ``other_tpdos = "keep"``);
5. writes the heartbeat producer time hexcal supervises (0x1017);
6. probes 0x1019: SYNC goes with or without a counter as the nodes expect (or writes the rig
   file's ``sync_counter``, refused by name on a device without 0x1019 unless it is 0);
7. reads what it needs to decode the position — 0x6004 itself, its data type (UNSIGNED32 or
   INTEGER32, from the object dictionary), the total measuring range 0x6002 (the position wraps
   there) — and reports the operating parameters 0x6000, the preset 0x6003 and, on a linear
   encoder, the measuring step 0x6005.

Mandatory for hexcal, refused by name when absent: 0x1000, 0x6004, the TPDO the rig file
names (with its mapping record) and 0x1017. Every other object the device lacks (SDO abort
0x06020000 / 0x06090011) is optional: skipped, logged, and listed in :attr:`NodeInfo.absent`.
Every other failure is an :class:`EncoderConfigError` naming the leg, the node, the exact object
and sub-index read or written, and what to do (:mod:`hexcal.drivers.can_sdo`).

Why not canopen's PDO maps (``node.tpdo[n].save()``): they walk the TPDOs the EDS lists and
write what the EDS says the record holds, so a generic EDS (four TPDOs) against a two-TPDO
device reads 0x1802 and fails on an object the device never had. The sequence here is CiA 301's
own, through canopen's SDO client, one named access at a time.
"""

from __future__ import annotations

import io
import logging
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import canopen
from canopen.objectdictionary import (
    INTEGER32,
    UNSIGNED32,
    ObjectDictionaryError,
    ODVariable,
    datatypes,
)

from hexcal.drivers.can_config import CanBusConfig, LegEncoderConfig, tpdo_cob_id
from hexcal.drivers.can_sdo import ABORT_READ_ONLY, EncoderConfigError, SdoAccess, where

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
#: Encoder types with a linear measuring step (0x6005).
LINEAR_TYPES = (0x0008, 0x000A)
#: CiA 301 object-dictionary indices used here.
DEVICE_TYPE, IDENTITY, HEARTBEAT_PRODUCER, SYNC_OVERFLOW = 0x1000, 0x1018, 0x1017, 0x1019
STORE_EDS, STORAGE_FORMAT = 0x1021, 0x1022
TPDO_COMM, TPDO_MAP = 0x1800, 0x1A00
OPERATING_PARAMETERS, TOTAL_RANGE, PRESET, POSITION, LINEAR_STEP = (
    0x6000,
    0x6002,
    0x6003,
    0x6004,
    0x6005,
)
#: A TPDO COB-ID's bits: 31 PDO invalid, 30 no RTR allowed.
PDO_INVALID, RTR_NOT_ALLOWED = 0x80000000, 0x40000000
#: CiA 301 data type codes → their names, for messages.
_TYPE_NAMES = {
    getattr(datatypes, n): n
    for n in dir(datatypes)
    if n.isupper() and isinstance(getattr(datatypes, n), int) and not n.endswith("TYPES")
}
#: 0x6004 (32 bits, sub-index 0) as a PDO mapping entry.
POSITION_ENTRY = 0x60040020
#: The SYNC counter overflow values CiA 301 allows: 0 (no counter) or 2..240.
SYNC_OVERFLOW_VALUES = (0, *range(2, 241))

#: Where a node's object dictionary came from (:attr:`NodeInfo.eds_source`).
EDS_RIG, EDS_DEVICE, EDS_GENERIC = "rig file", "stored in the device (0x1021)", "hexcal generic"


def generic_eds() -> Path:
    """The CiA 406 EDS shipped with hexcal (a generic absolute linear encoder)."""
    with resources.as_file(resources.files("hexcal").joinpath("data/cia406_encoder.eds")) as p:
        return Path(p)


def eds_for(bus: CanBusConfig, leg: LegEncoderConfig) -> Path:
    """The EDS leg ``leg``'s node is described by: its own, the bus's, else hexcal's generic."""
    path = leg.eds or bus.eds
    return Path(path) if path else generic_eds()


@dataclass(frozen=True)
class NodeInfo:
    """What the configuration step found on one encoder and what it set there."""

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
    #: Where the object dictionary came from: EDS_RIG, EDS_DEVICE or EDS_GENERIC.
    eds_source: str = EDS_GENERIC
    #: The TPDOs the device has (1..4) and each one's highest sub-index (0x18xx:00).
    tpdos: tuple[int, ...] = ()
    tpdo_highest: tuple[int, ...] = ()
    #: The TPDOs hexcal disabled (their COB-ID bit 31 set).
    disabled_tpdos: tuple[int, ...] = ()
    #: The device's mapping of ``tpdo`` is fixed (read-only) and already starts with 0x6004.
    static_mapping: bool = False
    #: The device has 0x1019 (it can take a SYNC counter).
    has_sync_counter: bool = False
    #: Manufacturer-specific objects (0x2000..0x5FFF) in the object dictionary used.
    manufacturer_objects: int = 0
    #: Optional objects the device does not have, as ``0x1018:02 (identity, product code)``.
    absent: tuple[str, ...] = field(default_factory=tuple)

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


def _remote(network: canopen.Network, leg: LegEncoderConfig, bus: CanBusConfig) -> Any:
    node = network[leg.node_id]
    if not isinstance(node, canopen.RemoteNode):
        raise EncoderConfigError(
            f"{leg.name}: node id 0x{leg.node_id:02X} on {bus.bus_name} is served by this host "
            "(a canopen LocalNode), not an encoder it can configure",
            leg.leg,
            leg.node_id,
        )
    return node


def _device_type(sdo: SdoAccess) -> int:
    leg, bus = sdo.leg, sdo.bus
    device_type = sdo.read(DEVICE_TYPE, 0, probe=True)
    if device_type is None:
        raise sdo.missing(
            DEVICE_TYPE,
            0,
            "every CANopen device has one (CiA 301)",
            f"is node id 0x{leg.node_id:02X} the encoder the rig file means? Fix the node id in "
            "the rig file or on the device",
        )
    if device_type & 0xFFFF != CIA406:
        raise EncoderConfigError(
            f"{leg.name} on {bus.bus_name} is not a CiA 406 encoder: its device type (0x1000) "
            f"is 0x{device_type:08X}, profile {device_type & 0xFFFF} — is node id "
            f"0x{leg.node_id:02X} another device? Fix the node id in the rig file or the device",
            leg.leg,
            leg.node_id,
        )
    return device_type


def _adopt_dictionary(
    node: Any,
    sdo: SdoAccess,
    bus: CanBusConfig,
    ident: tuple[int | None, ...],
    cache: dict[tuple[int, ...], bytes] | None,
) -> tuple[str, str]:
    """The object dictionary to use (module docstring, step 2), put into ``node``: (eds, source).
    ``cache``: EDS files already read from devices, by (vendor, product, revision): six encoders
    of one kind store one EDS, and a segmented SDO upload of tens of kB is not free."""
    leg = sdo.leg
    if leg.eds or bus.eds:
        return str(eds_for(bus, leg)), EDS_RIG
    key = tuple(v for v in ident[:3] if v is not None)
    known = cache is not None and len(key) == 3
    stored = cache.get(key) if known and cache is not None else None
    if stored is None:
        stored = sdo.read_bytes(STORE_EDS, 0, optional=True)
        if stored and known and cache is not None:
            cache[key] = stored
    if stored:
        fmt = sdo.read(STORAGE_FORMAT, 0, optional=True) or 0
        note = f"{len(stored)} bytes at 0x{STORE_EDS:04X}"
        if fmt != 0:
            log.warning(
                "%s stores its EDS in format %d (0x1022), which hexcal cannot read: using hexcal's "
                "generic EDS and what the device answers",
                leg.name,
                fmt,
            )
        else:
            try:
                text = io.StringIO(stored.decode("latin-1"))
                text.name = f"node-{leg.node_id:02X}.eds"  # import_od picks the parser by suffix
                od = canopen.import_od(text, leg.node_id)
            except (ObjectDictionaryError, ValueError, KeyError) as exc:
                log.warning(
                    "%s: the EDS stored at 0x1021 could not be read (%s): using hexcal's generic "
                    "EDS and what the device answers",
                    leg.name,
                    exc,
                )
            else:
                node.object_dictionary = od
                node.sdo.od = od
                return note, EDS_DEVICE
    return str(generic_eds()), EDS_GENERIC


def _probe_tpdos(sdo: SdoAccess) -> dict[int, int]:
    """{TPDO number: highest sub-index} of the TPDOs the device has (0x1800..0x1803 sub 0)."""
    found = {}
    for n in (1, 2, 3, 4):
        highest = sdo.read(TPDO_COMM + n - 1, 0, optional=True)
        if highest is not None:
            found[n] = highest
    return found


def _map_position(sdo: SdoAccess, tpdos: dict[int, int], bus: CanBusConfig) -> bool:
    """0x6004 alone in TPDO ``bus.tpdo``, on every SYNC (module docstring, step 4). Returns
    whether the device's mapping was fixed."""
    n, leg = bus.tpdo, sdo.leg
    comm, mapping = TPDO_COMM + n - 1, TPDO_MAP + n - 1
    if n not in tpdos:
        have = ", ".join(f"TPDO{k}" for k in tpdos) or "no TPDO"
        raise sdo.missing(
            comm,
            0,
            f"the device has {have} (probed 0x1800..0x1803 sub-index 0), not TPDO{n}",
            f"set can.tpdo in the rig file to one it has ({have}; CiA 406 makes TPDO2 the "
            "synchronous one where there are two)",
        )
    cob = sdo.read(comm, 1)
    assert cob is not None
    if not cob & PDO_INVALID:
        sdo.write(comm, 1, cob | PDO_INVALID)
    sdo.write(comm, 2, 1)  # synchronous, every SYNC
    fixed = False
    try:
        sdo.write(mapping, 0, 0)
    except EncoderConfigError as exc:
        if exc.abort_code != ABORT_READ_ONLY:
            raise
        fixed = True  # a static mapping (simple encoders): what it holds is checked below
    if fixed:
        count = sdo.read(mapping, 0)
        first = sdo.read(mapping, 1) if count else None
        if first != POSITION_ENTRY:
            raise EncoderConfigError(
                f"{leg.name} on {bus.bus_name}: TPDO{n}'s mapping is fixed on this device "
                f"({where(mapping, 0)} is read-only) and starts with "
                + (f"0x{first:08X}" if first is not None else "nothing")
                + f", not the position 0x{POSITION_ENTRY:08X} — set can.tpdo to a TPDO whose "
                "mapping starts with 0x6004, or map it with the vendor's tool",
                leg.leg,
                leg.node_id,
            )
    else:
        sdo.write(mapping, 1, POSITION_ENTRY)
        sdo.write(mapping, 0, 1)
    sdo.write(comm, 1, tpdo_cob_id(n, leg.node_id) | (cob & RTR_NOT_ALLOWED))
    return fixed


def _disable_others(sdo: SdoAccess, tpdos: dict[int, int], bus: CanBusConfig) -> tuple[int, ...]:
    """Disable the device's other TPDOs (their cyclic frames only load the bus)."""
    if bus.other_tpdos != "disable":
        return ()
    disabled = []
    for n in tpdos:
        if n == bus.tpdo:
            continue
        cob = sdo.read(TPDO_COMM + n - 1, 1)
        assert cob is not None
        if not cob & PDO_INVALID:
            sdo.write(TPDO_COMM + n - 1, 1, cob | PDO_INVALID)
            disabled.append(n)
    return tuple(disabled)


def _sync_counter(sdo: SdoAccess, bus: CanBusConfig) -> tuple[int, bool]:
    """(the SYNC counter overflow the node expects, whether it has 0x1019)."""
    current = sdo.read(SYNC_OVERFLOW, 0, optional=True)
    if bus.sync_counter is None:
        return current or 0, current is not None
    if current is None:
        if bus.sync_counter == 0:
            return 0, False
        raise sdo.missing(
            SYNC_OVERFLOW,
            0,
            f"it cannot take a SYNC with a counter (the rig file's sync_counter = {bus.sync_counter})",
            "set sync_counter = 0 in the rig file's [can] table, or leave it out: hexcal then "
            "sends SYNC as the devices expect",
        )
    sdo.write(SYNC_OVERFLOW, 0, bus.sync_counter)
    return bus.sync_counter, True


def _heartbeat(sdo: SdoAccess, bus: CanBusConfig) -> int:
    if sdo.read(HEARTBEAT_PRODUCER, 0, probe=True) is None:
        raise sdo.missing(
            HEARTBEAT_PRODUCER,
            0,
            "hexcal supervises each encoder by its heartbeat, and this one has none (node "
            "guarding alone, 0x100C/0x100D, is not supported)",
            "use an encoder with a heartbeat producer (CiA 301 since version 4), or set "
            "can.configure = false and supervise it by other means",
        )
    sdo.write(HEARTBEAT_PRODUCER, 0, bus.heartbeat_period_ms)
    return bus.heartbeat_period_ms


def _position_type(node: Any, sdo: SdoAccess) -> str:
    """INTEGER32 or UNSIGNED32, from the object dictionary; 0x6004 read once to be sure the
    device has it."""
    if sdo.read(POSITION, 0, probe=True) is None:
        raise sdo.missing(
            POSITION,
            0,
            "hexcal reads the leg length from it (CiA 406's position value; a multi-sensor "
            "device may report it in 0x6020 instead)",
            "check that this is a single-sensor CiA 406 encoder, or set the device to report its "
            "position in 0x6004 with the vendor's tool",
        )
    od = node.object_dictionary.get(POSITION)
    if od is not None and not isinstance(od, ODVariable):
        raise EncoderConfigError(
            f"{sdo.leg.name}: 0x{POSITION:04X} (position value) is not a single variable in its "
            "EDS — give the vendor's EDS (can.eds in the rig file)",
            sdo.leg.leg,
            sdo.leg.node_id,
        )
    if od is None or od.data_type == INTEGER32:
        return "INTEGER32"
    if od.data_type == UNSIGNED32:
        return "UNSIGNED32"
    # Mapped as 32 bits and read as one of the two: any other type would be decoded as
    # something it is not (a 16-bit position's neighbour bytes, a REAL32's bit pattern).
    raise EncoderConfigError(
        f"{sdo.leg.name}: 0x{POSITION:04X} (position value) is "
        f"{_TYPE_NAMES.get(od.data_type, f'data type 0x{od.data_type:04X}')} in its EDS; hexcal "
        "reads a 32-bit position (INTEGER32 or UNSIGNED32, as CiA 406 types it) — give the "
        "vendor's EDS (can.eds in the rig file), or set the device to a 32-bit position",
        sdo.leg.leg,
        sdo.leg.node_id,
    )


def configure_node(
    network: canopen.Network,
    leg: LegEncoderConfig,
    bus: CanBusConfig,
    eds_cache: dict[tuple[int, ...], bytes] | None = None,
) -> NodeInfo:
    """Set up leg ``leg``'s encoder (steps in the module docstring); the node must be in
    PRE-OPERATIONAL (it may be OPERATIONAL for the reads, not for the PDO writes). Returns what
    was found and set; raises :class:`EncoderConfigError`. ``eds_cache``: a dict kept across the
    nodes of one start, so that an EDS stored in the devices is read from the first of a kind
    only."""
    node = _remote(network, leg, bus)
    node.sdo.RESPONSE_TIMEOUT = bus.sdo_timeout_s
    sdo = SdoAccess(node, leg, bus)
    device_type = _device_type(sdo)
    ident = tuple(sdo.read(IDENTITY, s, optional=True) for s in (1, 2, 3, 4))
    eds, source = _adopt_dictionary(node, sdo, bus, ident, eds_cache)
    position_type = _position_type(node, sdo)
    tpdos = _probe_tpdos(sdo)
    fixed = _map_position(sdo, tpdos, bus)
    disabled = _disable_others(sdo, tpdos, bus)
    heartbeat_ms = _heartbeat(sdo, bus)
    overflow, has_counter = _sync_counter(sdo, bus)
    total_range = sdo.read(TOTAL_RANGE, 0, optional=True) or None
    operating = sdo.read(OPERATING_PARAMETERS, 0, optional=True)
    preset = sdo.read(PRESET, 0, optional=True)
    linear = device_type >> 16 in LINEAR_TYPES
    step_nm = sdo.read(LINEAR_STEP, 1, optional=True) if linear else None
    od = node.object_dictionary
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
        eds=eds,
        eds_source=source,
        tpdos=tuple(tpdos),
        tpdo_highest=tuple(tpdos.values()),
        disabled_tpdos=disabled,
        static_mapping=fixed,
        has_sync_counter=has_counter,
        manufacturer_objects=sum(1 for i in od if 0x2000 <= i <= 0x5FFF),
        absent=tuple(sdo.absent),
    )
    log.info(
        "%s: %s, %s, TPDO%d on every SYNC; object dictionary %s; absent: %s",
        leg.name,
        info.encoder_type,
        info.identity,
        bus.tpdo,
        source,
        ", ".join(info.absent) or "nothing asked for",
    )
    return info


__all__ = [
    "CIA406",
    "EDS_DEVICE",
    "EDS_GENERIC",
    "EDS_RIG",
    "ENCODER_TYPES",
    "EncoderConfigError",
    "NodeInfo",
    "configure_node",
    "eds_for",
    "generic_eds",
]
