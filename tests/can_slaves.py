"""CANopen slaves hexcal did not write, for the set-up tests: canopen's own ``LocalNode`` (its NMT
slave, heartbeat producer and SDO server) built from an EDS by canopen's object-dictionary
import, at the EDS's factory values.

canopen's LocalNode does not answer SYNC with its synchronous TPDOs, so that — and only that —
is written here, from CiA 301: on each SYNC, while OPERATIONAL, every TPDO whose COB-ID is valid
(bit 31 clear) and whose transmission type is 1..240 sends, every that-many SYNCs, the objects
its mapping record lists, each at the width the entry gives, as the object dictionary types it.

Timing as on a real bus: an encoder latches at the SYNC and its answer is on the wire within
microseconds, while this Python thread may get to the SYNC milliseconds later on a busy machine.
On a virtual bus opened with ``preserve_timestamps`` (:func:`slave_network`) each answer is
stamped as a CAN controller would stamp it: the SYNC's time plus 100 µs.
"""

from __future__ import annotations

import time
from pathlib import Path

import can
import canopen
from canopen.objectdictionary import ODVariable

#: How long after the SYNC a slave's answer is on the wire, s.
LATENCY_S = 100e-6


def slave_network(channel: str) -> canopen.Network:
    """The slaves' side of a virtual bus: its frames keep the times they are stamped with."""
    net = canopen.Network()
    net.connect(interface="virtual", channel=channel, preserve_timestamps=True)
    return net


class ForeignEncoder:
    """A CiA 406 slave on ``net`` at ``node_id`` from ``eds``. ``position()`` gives 0x6004 (counts)
    whenever it is read or sent. ``store_eds``: the device keeps its EDS at 0x1021 (as many do).
    ``accesses``: every SDO access the master made, as (op, index, sub), op "read" / "write";
    ``refuse``: {(op, index, sub): abort code} the node answers instead."""

    def __init__(
        self,
        net: canopen.Network,
        node_id: int,
        eds: Path,
        position,
        *,
        store_eds: bool = False,
    ):
        self.net, self.position = net, position
        self.node = canopen.LocalNode(
            node_id, canopen.objectdictionary.import_od(str(eds), node_id)
        )
        if store_eds:
            self.node.data_store.setdefault(0x1021, {})[0] = eds.read_bytes()
        self.accesses: list[tuple[str, int, int]] = []
        self.refuse: dict[tuple[str, int, int], int] = {}
        self.node.add_read_callback(self._read)
        # The master's accesses are the SDO server's, which check access rights; the node's own
        # (its NMT slave reading 0x1017) do not.
        get_data, set_data = self.node.get_data, self.node.set_data

        def traced_get(index, subindex, check_readable=False):
            if check_readable:
                self._access("read", index, subindex)
            return get_data(index, subindex, check_readable)

        def traced_set(index, subindex, data, check_writable=False):
            if check_writable:
                self._access("write", index, subindex)
            return set_data(index, subindex, data, check_writable)

        self.node.get_data, self.node.set_data = traced_get, traced_set
        self.sync_count: dict[int, int] = {}
        net.add_node(self.node)
        net.subscribe(0x080, self._on_sync)
        self.node.nmt.send_command(0x81)  # boot-up
        self.node.nmt.send_command(0x80)  # pre-operational, heartbeat per 0x1017 (0: none)

    def _access(self, op: str, index: int, sub: int) -> None:
        from canopen.sdo import SdoAbortedError

        self.accesses.append((op, index, sub))
        code = self.refuse.get((op, index, sub))
        if code is not None:
            raise SdoAbortedError(code)

    def _read(self, index, subindex, od):
        return self.position() if index == 0x6004 else None

    def value(self, index: int, sub: int = 0) -> int:
        """An object's value as the node holds it (no SDO, no callbacks)."""
        obj = self.node.object_dictionary[index]
        var = obj if isinstance(obj, ODVariable) else obj[sub]
        raw = self.node.data_store.get(index, {}).get(sub)
        return int(var.decode_raw(raw)) if raw is not None else int(var.default or 0)

    def _payload(self, n: int) -> bytes:
        out = b""
        for s in range(1, self.value(0x1A00 + n, 0) + 1):
            entry = self.value(0x1A00 + n, s)
            index, sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
            obj = self.node.object_dictionary[index]
            var = obj if isinstance(obj, ODVariable) else obj[sub]
            if index == 0x6004:
                out += var.encode_raw(self.position())
            else:
                raw = self.node.data_store.get(index, {}).get(sub)
                out += (raw if raw is not None else var.encode_raw(var.default or 0))[: bits // 8]
        return out

    def _on_sync(self, can_id, data, timestamp):
        if self.node.nmt.state != "OPERATIONAL":
            return
        for n in range(4):
            if 0x1800 + n not in self.node.object_dictionary:
                continue
            cob, tt = self.value(0x1800 + n, 1), self.value(0x1800 + n, 2)
            if cob & 0x80000000 or not 1 <= tt <= 240:
                continue
            self.sync_count[n] = self.sync_count.get(n, 0) + 1
            if self.sync_count[n] % tt == 0:
                msg = can.Message(
                    arbitration_id=cob & 0x7FF,
                    data=self._payload(n),
                    is_extended_id=False,
                    timestamp=min(timestamp + LATENCY_S, time.time()),
                )
                with self.net.send_lock:
                    assert self.net.bus is not None
                    self.net.bus.send(msg)

    def close(self) -> None:
        self.node.nmt.stop_heartbeat()
