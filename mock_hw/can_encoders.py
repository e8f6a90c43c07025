"""Six mock CiA 406 leg encoders on a python-can bus, fed by a :class:`MockRobot`: each is a
``canopen.LocalNode`` built from the same EDS the driver reads (hexcal's generic CiA 406 one
unless the configuration names another), and each **starts at its factory settings**:

- boot-up ``0x700 + node [0x00]`` at start, then PRE-OPERATIONAL; NMT commands (node 0 = all):
  start, stop, pre-operational, reset node (every object back to its factory value) and reset
  communication (0x1000–0x1FFF back);
- heartbeat producer 0x1017 = 0: **no heartbeat** until a master writes a period;
- TPDO1 ``0x180 + node``: 0x6004, transmission type 0xFE — sent **cyclically** every 0x6200 ms
  (100 ms) while OPERATIONAL, not latched at SYNC; TPDO2 ``0x280 + node``: 0x6004 on every
  SYNC; TPDO3/4 invalid;
- SYNC counter overflow 0x1019 = 0: a SYNC must be empty. A SYNC whose length does not match
  (a counter byte when 0x1019 is 0, none when it is 2..240) is answered, as CiA 301 asks, with
  EMCY 0x8240 (unexpected SYNC data length), once, and an error reset when SYNCs match again;
- SDO server (canopen's) over the object dictionary, with the device's rules: the PDO
  communication and mapping objects and 0x1019 are written only in PRE-OPERATIONAL (abort
  0x08000022 otherwise), a mapping only while its PDO is invalid and its count is 0, and only
  objects the EDS marks mappable (abort 0x06040041);
- LSS slave (CiA 305) on 0x7E5/0x7E4: switch state global and selective (vendor, product,
  revision, serial), inquire identity and node id, configure node id and bit timing, store;
  a new node id takes effect at the next NMT reset (node or communication).

So the driver reads positions from them only by configuring them: TPDO2 on SYNC, the heartbeat
period, an empty SYNC. The position a node sends (in its synchronous TPDO) is latched at the
SYNC: round((reading_mm − zero_mm) × counts_per_mm × sign) — the inverse of the driver's
conversion, so signs, zeros and scales are tested — encoded as the EDS types 0x6004.

Timing as on a real bus: a CiA 406 encoder latches its position in hardware at the SYNC and
answers within microseconds; a Python thread may handle the SYNC milliseconds later. So each node
latches the robot's readings at the SYNC's bus time (:meth:`MockRobot.encoder_readings` with
``at``), and, on a virtual bus this object opens, stamps its TPDO with the time it would have
been on the wire: the SYNC's bus time + ``latency_s`` + its jitter delay, as a CAN controller's
receive timestamp would read (python-can's ``preserve_timestamps``). Everything else it sends
is stamped when sent.

Faults, injectable while running: :meth:`silence` (a node stops: cable cut), :meth:`drop_next`
(a TPDO lost), :meth:`error_frames`, :meth:`bus_off` / :meth:`recover`, :meth:`reboot` (a node
resets: its factory settings again; with ``zero_shift_mm`` it comes back off by a lost
preset), :meth:`emergency` (an encoder alarm: EMCY), ``jitter_s``,
:meth:`stamp_next` / :meth:`step_clock` (the bus clock's faults), and at construction
``device_types`` (a node that is not a 406 encoder), ``sdo_aborts`` (a node refusing a write)
and ``sdo_deaf`` (nodes that do not answer SDO). The virtual bus has no physical layer, so
bus-off is emulated the way a SocketCAN controller reports it: an error frame with the
CAN_ERR_BUSOFF class, then silence.

``factory_node_ids`` {leg: node id} starts a node at another node id than the configuration's
(as out of its box): LSS (``hexcal devices can-setup``) sets it.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Iterable, Mapping
from pathlib import Path

import can
import canopen
import numpy as np

from hexcal.drivers.base import Device
from hexcal.drivers.can_config import (
    HEARTBEAT_BASE,
    NMT_COB_ID,
    SYNC_COB_ID,
    CanBusConfig,
)
from hexcal.drivers.can_nodes import eds_for
from hexcal.mock_hw.can_node import (
    _NMT_RESETS,
    CAN_ERR_BUSERROR,
    CAN_ERR_BUSOFF,
    CAN_ERR_PROT,
    CAN_ERR_RESTARTED,
    EMCY_SYNC_LENGTH,
    LSS_BIT_TIMING,
    LSS_MASTER_COB_ID,
    LSS_SLAVE_COB_ID,
    OPERATIONAL,
    PRE_OPERATIONAL,
    REGISTER_COMMUNICATION,
    Encoder,
    NodeNetwork,
    Periodic,
    _position_variable,
)
from hexcal.mock_hw.robot import MockRobot

log = logging.getLogger(__name__)


class MockEncoderNodes(Device):
    """The six leg encoders of ``config`` answering on ``bus`` (None: open ``config.interface``/
    ``config.channel`` at :meth:`start`, close it at :meth:`stop`), at their factory settings
    (module docstring).

    ``jitter_s``: each synchronous TPDO is delayed by U(0, jitter_s) s. ``seed`` seeds the jitter.
    ``eds``: the object dictionary the nodes are built from — one EDS for all six, or
    {leg: EDS}; by default the one the configuration names for the driver (the nodes then agree
    with the driver by construction: give another to test the driver against a device it was
    not told about). A node whose EDS has 0x1021 (store EDS) serves that file's text there.
    ``factory_node_ids`` {leg: node id}: a node out of its box, answering at another node id
    than the configuration's until LSS sets it. ``device_types`` {leg: 0x1000 value}: a node
    that is another kind of device. ``sdo_aborts`` {leg: (index, abort code)}: a node refusing
    to write an object. ``sdo_deaf``: legs whose node does not answer SDO. Observables for tests:
    ``states`` {leg: NMT state}, ``nmt_log`` [(cs, node)], ``history`` [(SYNC counter,
    readings (6,) mm latched at that SYNC)] (the last ``log_len``; read it through
    :meth:`latched` while running), ``syncs_seen``, ``encoders`` {leg: the node's state}.
    """

    def __init__(
        self,
        robot: MockRobot,
        config: CanBusConfig,
        bus: can.BusABC | None = None,
        *,
        jitter_s: float = 0.0,
        latency_s: float = 100e-6,
        seed: int = 0,
        log_len: int = 1_000,
        factory_node_ids: dict[int, int] | None = None,
        device_types: dict[int, int] | None = None,
        sdo_aborts: dict[int, tuple[int, int]] | None = None,
        sdo_deaf: Iterable[int] = (),
        eds: str | Path | Mapping[int, str | Path] | None = None,
    ):
        self.robot = robot
        self.config = config
        self.jitter_s = jitter_s
        self.latency_s = latency_s
        self._bus_in = bus
        self._bus: can.BusABC | None = None
        self._network: NodeNetwork | None = None
        self._wire_times = False
        self._rng = np.random.default_rng(seed)
        self._lock = threading.Lock()
        self._send_lock = threading.RLock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._device_types = dict(device_types or {})
        self._sdo_aborts = dict(sdo_aborts or {})
        self._sdo_deaf = set(sdo_deaf)
        ids = factory_node_ids or {}
        if eds is None or isinstance(eds, Mapping):
            per_leg = {
                c.leg: str((eds or {}).get(c.leg) or eds_for(config, c)) for c in config.legs
            }
        else:
            per_leg = {c.leg: str(eds) for c in config.legs}
        self.encoders: dict[int, Encoder] = {
            c.leg: Encoder(
                self, c.leg, ids.get(c.leg, c.node_id), per_leg[c.leg], 4_060_000 + c.leg
            )
            for c in config.legs
        }
        self._silent = dict.fromkeys(range(1, 7), False)
        self._zero_shift = dict.fromkeys(range(1, 7), 0.0)  # mm a reboot's lost preset adds
        self._drop = dict.fromkeys(range(1, 7), 0)
        self._skew_next: dict[int, float] = {}  # leg -> s added to its next TPDO's stamp
        self._clock_step_s = 0.0  # s added to every stamp (the interface's clock jumped)
        self._bus_off = False
        self._scheduled: list[tuple[float, int, can.Message]] = []
        self._periodic_tasks: list[Periodic] = []
        self._seq = itertools.count()
        self.nmt_log: list[tuple[int, int]] = []
        self.history: deque[tuple[int, np.ndarray]] = deque(maxlen=log_len)
        self.syncs_seen = 0
        #: When the last SYNCs went on the bus (s, monotonic), oldest first.
        self.sync_times: deque[float] = deque(maxlen=16)
        self._offset, self._offset_at = 0.0, -math.inf  # see _wall_minus_monotonic

    @property
    def states(self) -> dict[int, int]:
        """{leg: NMT state code}."""
        return {leg: e.state for leg, e in self.encoders.items()}

    # -- lifecycle -------------------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        return self._thread is not None

    def open(self) -> MockEncoderNodes:
        return self.start()

    def close(self) -> None:
        self.stop()

    def start(self) -> MockEncoderNodes:
        """Open the bus (if not given), boot the six nodes (boot-up, PRE-OPERATIONAL) and start
        answering."""
        if self._thread is not None:
            return self
        if self._bus_in is not None:
            self._bus = self._bus_in
        else:
            kwargs = self.config.bus_kwargs()
            if self.config.interface == "virtual":
                kwargs["preserve_timestamps"] = True  # the wire times set in _on_sync
            self._bus = can.Bus(**kwargs)
        self._wire_times = bool(getattr(self._bus, "preserve_timestamps", False))
        self._stop.clear()
        net = self._network = NodeNetwork(self, self._bus)
        net.NOTIFIER_CYCLE = 0.05
        for enc in self.encoders.values():
            enc.attach(net)
        net.subscribe(NMT_COB_ID, self._on_nmt)
        net.subscribe(SYNC_COB_ID, self._on_sync)
        net.subscribe(LSS_MASTER_COB_ID, self._on_lss)
        net.connect()
        for enc in self.encoders.values():
            self._boot(enc)
        self._thread = threading.Thread(target=self._run, name="hexcal-mock-encoders", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop answering; close the bus if this object opened it."""
        if self._thread is None:
            return
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._thread = None
        net = self._network
        if net is not None and net.notifier is not None:
            net.notifier.stop(1.0)
        if self._bus_in is None and self._bus is not None:
            self._bus.shutdown()
        self._bus = None
        self._network = None

    def latched(self) -> dict[int, np.ndarray]:
        """{SYNC counter: readings (6,) mm latched at that SYNC}, a snapshot (the latest SYNC
        wins when the counter wraps; with SYNCs without counter, the key is the SYNC's number
        since start)."""
        with self._lock:
            return {c: r.copy() for c, r in self.history}

    # -- fault injection -------------------------------------------------------------------------
    def silence(self, leg: int, silent: bool = True) -> None:
        """Leg ``leg``'s node goes quiet (no heartbeat, no TPDO, deaf to NMT and SDO) — or comes
        back, keeping its NMT state, as after a reconnected cable."""
        with self._lock:
            self._silent[leg] = silent

    def drop_next(self, leg: int, n: int = 1) -> None:
        """Lose the next ``n`` synchronous TPDOs of leg ``leg`` (the SYNCs still happen)."""
        with self._lock:
            self._drop[leg] += n

    def error_frames(self, n: int = 1) -> None:
        """Put ``n`` error frames (protocol violation, bus error) on the bus now."""
        for _ in range(n):
            self._send(
                can.Message(
                    arbitration_id=CAN_ERR_PROT | CAN_ERR_BUSERROR,
                    is_error_frame=True,
                    data=bytes(8),
                )
            )

    def bus_off(self) -> None:
        """Emulate the controller going bus-off: a CAN_ERR_BUSOFF error frame, then nothing is
        sent until :meth:`recover`."""
        with self._send_lock:  # no data frame may slip out after the error frame
            with self._lock:
                self._bus_off = True
                self._scheduled.clear()
            self._send(
                can.Message(arbitration_id=CAN_ERR_BUSOFF, is_error_frame=True, data=bytes(8))
            )

    def recover(self) -> None:
        """End an emulated bus-off: a CAN_ERR_RESTARTED error frame, then normal traffic."""
        with self._send_lock:
            self._send(
                can.Message(arbitration_id=CAN_ERR_RESTARTED, is_error_frame=True, data=bytes(8))
            )
            with self._lock:
                self._bus_off = False

    def stamp_next(self, leg: int, offset_s: float) -> None:
        """Stamp leg ``leg``'s next TPDO ``offset_s`` s off the bus clock (one corrupt
        timestamp). Needs wire times (a virtual bus this object opened)."""
        self._need_wire_times("stamp_next")
        with self._lock:
            self._skew_next[leg] = self._skew_next.get(leg, 0.0) + offset_s

    def step_clock(self, offset_s: float) -> None:
        """Step the bus clock by ``offset_s`` s: every frame from now on is stamped that much off
        (negative: the clock was reset back). Needs wire times (a virtual bus this object
        opened)."""
        self._need_wire_times("step_clock")
        with self._send_lock:  # frames after the step only
            self._clock_step_s += offset_s

    def _need_wire_times(self, what: str) -> None:
        if not self._wire_times:
            raise RuntimeError(
                f"{what}() needs the mock to stamp its frames (python-can's virtual bus opened by "
                "MockEncoderNodes with preserve_timestamps): on a real bus the interface stamps them"
            )

    def reboot(self, leg: int, zero_shift_mm: float = 0.0) -> None:
        """Leg ``leg``'s node resets (a supply dip): boot-up, PRE-OPERATIONAL, factory settings
        (no heartbeat, TPDO2 on SYNC) — until the master sets it up again. ``zero_shift_mm``:
        an encoder that keeps no preset (incremental, a lost battery) comes back reading that
        much more from then on."""
        with self._lock:
            self._zero_shift[leg] += zero_shift_mm
        enc = self.encoders[leg]
        enc.factory_reset(communication_only=False)
        self._boot(enc)

    def emergency(self, leg: int, code: int, register: int = 0x01, data: bytes = bytes(5)) -> None:
        """Leg ``leg``'s node sends EMCY ``code`` with error register ``register`` (an encoder
        alarm); ``code`` 0 with register 0 is the error reset."""
        self.encoders[leg].node.emcy.send(code, register, data)

    # -- the nodes' work -------------------------------------------------------------------------
    def _leg_of(self, can_id: int) -> int | None:
        node_id = can_id & 0x7F
        if can_id in (LSS_SLAVE_COB_ID,) or can_id < 0x80 or can_id > 0x7FF:
            return None
        for leg, enc in self.encoders.items():
            if enc.node_id == node_id:
                return leg
        return None

    def _send(self, msg: can.Message) -> None:
        bus = self._bus
        if bus is None:
            return
        with self._send_lock:
            if self._bus_off and not msg.is_error_frame:
                return  # decided before bus_off(), sent after: a bus-off controller sends nothing
            if not msg.is_error_frame:
                leg = self._leg_of(msg.arbitration_id)
                if leg is not None and self._silent[leg]:
                    return
            if self._wire_times:
                msg.timestamp = (msg.timestamp or time.time()) + self._clock_step_s
            try:
                bus.send(msg)
            except can.CanError as exc:  # a mock must not die on a full queue: log and go on
                log.warning("mock encoders could not send %s: %s", msg, exc)

    def _periodic(self, can_id: int, data: bytes, period: float) -> Periodic:
        task = Periodic(self, can_id, data, period)
        with self._lock:
            self._periodic_tasks = [t for t in self._periodic_tasks if not t.stopped] + [task]
        return task

    def _boot(self, enc: Encoder) -> None:
        """Power-up or reset: boot-up message, then PRE-OPERATIONAL with the heartbeat 0x1017
        says (none at the factory setting)."""
        enc.node.nmt.send_command(0x81)  # INITIALISING: canopen sends the boot-up message
        enc.node.nmt.send_command(0x80)  # → PRE-OPERATIONAL, heartbeat per 0x1017

    def _run(self) -> None:
        while not self._stop.is_set():
            now = time.monotonic()
            with self._lock:
                tasks = [t for t in self._periodic_tasks if not t.stopped and now >= t.next]
            for t in tasks:
                self._send(can.Message(arbitration_id=t.can_id, data=t.data, is_extended_id=False))
                t.next += t.period
                if now - t.next > t.period:  # stalled: do not burst
                    t.next = now + t.period
            self._cyclic(now)
            self._send_due(now)
            with self._lock:
                due = [self._scheduled[0][0]] if self._scheduled else []
                due += [t.next for t in self._periodic_tasks if not t.stopped]
            wake = min([*due, now + 0.01])
            self._stop.wait(max(0.0, min(wake - time.monotonic(), 0.05)))

    def _cyclic(self, now: float) -> None:
        """Asynchronous TPDOs (transmission type 0xFE/0xFF) of OPERATIONAL nodes, every event
        timer (or 0x6200 cyclic timer) ms — the factory TPDO1 of a CiA 406 encoder."""
        for enc in self.encoders.values():
            if enc.state != OPERATIONAL or self._silent[enc.leg]:
                continue
            for n in (1, 2, 3, 4):
                if 0x1800 + n - 1 not in enc.node.object_dictionary:
                    continue
                cob = enc.value(0x1800 + n - 1, 1)
                if cob & 0x80000000 or enc.value(0x1800 + n - 1, 2) < 0xFE:
                    continue
                # The event timer (sub-index 5, where the device has one), else CiA 406's
                # cyclic timer 0x6200.
                period_ms = enc.value(0x1800 + n - 1, 5, default=0) or enc.value(0x6200, default=0)
                if not period_ms:
                    continue
                if now >= enc.next_cyclic[n]:
                    enc.next_cyclic[n] = now + period_ms / 1000
                    reading = float(self.robot.encoder_readings()[enc.leg - 1])
                    self._send(
                        can.Message(
                            arbitration_id=cob & 0x7FF,
                            data=self._pdo_data(enc, n, reading),
                            is_extended_id=False,
                        )
                    )

    def _send_due(self, now: float) -> None:
        while True:
            with self._lock:
                if not self._scheduled or self._scheduled[0][0] > now:
                    return
                _, _, msg = heapq.heappop(self._scheduled)
            self._send(msg)

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if len(data) < 2:
            return
        cs, node = data[0], data[1]
        self.nmt_log.append((cs, node))
        for enc in list(self.encoders.values()):
            if node not in (0, enc.node_id) or self._silent[enc.leg] or self._bus_off:
                continue
            if cs in _NMT_RESETS:
                enc.factory_reset(communication_only=cs == 0x82)
                self._boot(enc)
            elif cs in (0x01, 0x02, 0x80):
                enc.node.nmt.send_command(cs)
                if not enc.value(0x1017):
                    continue  # heartbeat off (the factory setting): nothing tells the state
                # Answer at once: the master need not wait a heartbeat period.
                self._send(
                    can.Message(
                        arbitration_id=HEARTBEAT_BASE + enc.node_id,
                        data=[enc.state],
                        is_extended_id=False,
                    )
                )

    def _counts(self, enc: Encoder, reading_mm: float) -> int | float:
        """A reading as the node's 0x6004 value: counts, clipped or wrapped as its type is
        (INTEGER32 clips; an unsigned type wraps at 0x6002 or its own range; a shorter signed
        type wraps at its own; a REAL type carries the counts as a number)."""
        cfg = self.config.leg(enc.leg)
        counts = cfg.mm_to_counts(reading_mm)
        od = _position_variable(enc.node)
        kind = od.data_type
        if kind in canopen.objectdictionary.FLOAT_TYPES:
            return float(counts)
        bits = len(od)
        if kind == canopen.objectdictionary.INTEGER32:
            return min(max(counts, -(2**31)), 2**31 - 1)
        if kind in canopen.objectdictionary.SIGNED_TYPES:
            return (counts + 2 ** (bits - 1)) % 2**bits - 2 ** (bits - 1)
        span = enc.value(0x6002, default=0) if bits == 32 else 0
        return counts % (span or 2**bits)

    def _pdo_data(self, enc: Encoder, n: int, reading_mm: float) -> bytes:
        """TPDO ``n``'s payload: its mapped objects, 0x6004 from ``reading_mm``."""
        out = b""
        for s in range(1, enc.value(0x1A00 + n - 1, 0) + 1):
            entry = enc.value(0x1A00 + n - 1, s)
            index, sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
            if index == 0x6004:
                od = _position_variable(enc.node)
                out += od.encode_raw(self._counts(enc, reading_mm))
            else:
                out += enc.node.get_data(index, sub)[: bits // 8]
        return out

    def _wall_minus_monotonic(self, now: float) -> float:
        """The wall clock less the monotonic one (s), measured again each second: across a wall
        clock read bracketed most tightly by two monotonic ones. Read once in passing, a thread
        held back between the two reads (a busy host) would put the SYNC milliseconds early."""
        if now - self._offset_at > 1.0:
            gap, offset = math.inf, 0.0
            for _ in range(5):
                m1 = time.monotonic()
                wall = time.time()
                m2 = time.monotonic()
                if m2 - m1 < gap:
                    gap, offset = m2 - m1, wall - (m1 + m2) / 2
            self._offset, self._offset_at = offset, now
        return self._offset

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        t = time.monotonic()
        # The SYNC's bus time (wall clock on python-can's buses) on the monotonic clock.
        t_bus = timestamp or time.time()
        t_sync = t_bus - self._wall_minus_monotonic(t)
        # Latched at the SYNC's instant (never in the future: now at the latest), so each SYNC
        # is one measurement of the robot's encoder stream, in order (MockRobot's noise).
        at = min(t_sync, t) if self.robot.clock is time.monotonic else None
        readings = self.robot.encoder_readings(at)  # latched at the SYNC, as a CiA 406 encoder does
        counter = data[0] if len(data) >= 1 else self.syncs_seen + 1
        out: list[tuple[float, can.Message]] = []
        with self._lock:
            self.syncs_seen += 1
            self.sync_times.append(t_sync)
            self.history.append((counter, readings))
            if self._bus_off:
                return
        for enc in self.encoders.values():
            leg = enc.leg
            if self._silent[leg] or enc.state not in (OPERATIONAL, PRE_OPERATIONAL):
                continue
            overflow = enc.value(0x1019, default=0)
            wrong = len(data) != (1 if overflow >= 2 else 0)
            if wrong != enc.sync_error:  # CiA 301: EMCY on the error, a reset once it is gone
                enc.sync_error = wrong
                enc.node.emcy.send(
                    EMCY_SYNC_LENGTH if wrong else 0, REGISTER_COMMUNICATION if wrong else 0
                )
            if enc.state != OPERATIONAL:
                continue
            for n in (1, 2, 3, 4):
                if 0x1800 + n - 1 not in enc.node.object_dictionary:
                    continue
                cob = enc.value(0x1800 + n - 1, 1)
                tt = enc.value(0x1800 + n - 1, 2)
                if cob & 0x80000000 or tt > 240:
                    continue
                enc.sync_count[n] += 1
                if enc.sync_count[n] < max(tt, 1):
                    continue
                enc.sync_count[n] = 0
                with self._lock:
                    if self._drop[leg] > 0:
                        self._drop[leg] -= 1
                        continue
                    skew = self._skew_next.pop(leg, 0.0)
                delay = float(self._rng.uniform(0.0, self.jitter_s)) if self.jitter_s > 0 else 0.0
                frame = can.Message(
                    arbitration_id=cob & 0x7FF,
                    data=self._pdo_data(enc, n, float(readings[leg - 1]) + self._zero_shift[leg]),
                    is_extended_id=False,
                    # Never later than now (+ its delay): a wire time is never in the future.
                    timestamp=min(t_bus + self.latency_s, time.time()) + delay + skew
                    if self._wire_times
                    else 0.0,
                )
                out.append((delay, frame))
        with self._lock:
            for delay, frame in out:
                if delay > 0:
                    heapq.heappush(self._scheduled, (t + delay, next(self._seq), frame))
        for delay, frame in out:
            if delay == 0:
                self._send(frame)

    # -- LSS slave (CiA 305) ---------------------------------------------------------------------
    def _lss_reply(self, payload: bytes) -> None:
        self._send(
            can.Message(
                arbitration_id=LSS_SLAVE_COB_ID, data=payload.ljust(8, b"\0"), is_extended_id=False
            )
        )

    def _on_lss(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if len(data) < 1:
            return
        cs = data[0]
        value = int.from_bytes(bytes(data[1:5]).ljust(4, b"\0"), "little")
        for enc in self.encoders.values():
            if self._silent[enc.leg]:
                continue
            ident = [enc.value(0x1018, s, default=0) for s in (1, 2, 3, 4)]
            reply = self._lss_reply
            if cs == 0x04:  # switch state global
                enc.lss_config = data[1] == 1
                enc.lss_selective = []
            elif 0x40 <= cs <= 0x43:  # switch state selective: vendor, product, revision, serial
                enc.lss_selective = [*enc.lss_selective[: cs - 0x40], value]
                if cs == 0x43 and enc.lss_selective == ident:
                    enc.lss_config = True
                    reply(bytes([0x44]))
            elif not enc.lss_config:
                continue
            elif cs == 0x11:  # configure node id
                ok = 1 <= data[1] <= 127 or data[1] == 0xFF
                if ok:
                    enc.pending_id = data[1]
                reply(bytes([0x11, 0 if ok else 1]))
            elif cs == 0x13:  # configure bit timing: table 0, index
                ok = data[1] == 0 and data[2] in LSS_BIT_TIMING
                if ok:
                    enc.bitrate = LSS_BIT_TIMING[data[2]]
                reply(bytes([0x13, 0 if ok else 1]))
            elif cs == 0x17:  # store configuration
                reply(bytes([0x17, 0]))
            elif 0x5A <= cs <= 0x5D:  # inquire identity
                reply(bytes([cs]) + ident[cs - 0x5A].to_bytes(4, "little"))
            elif cs == 0x5E:  # inquire node id
                reply(bytes([0x5E, enc.node_id]))


__all__ = ["MockEncoderNodes"]
