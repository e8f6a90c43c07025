"""Six mock CANopen (CiA 406) leg-encoder nodes on a python-can bus, fed by a :class:`MockRobot`.

They speak the wire protocol the real encoders do, so the real driver is what the tests
exercise:

- boot-up ``0x700 + node [0x00]`` at start, then PRE-OPERATIONAL;
- NMT ``0x000 [cs, node]`` (node 0 = all): start, stop, pre-operational, reset;
- heartbeat ``0x700 + node [state]`` every ``heartbeat_period_s`` and on each state change;
- on SYNC ``0x080``, every OPERATIONAL node latches the robot's encoder readings and sends TPDO1
  ``0x180 + node`` with 0x6004 = round((reading_mm − zero_mm) × counts_per_mm × sign) as INTEGER32
  little endian — the inverse of the driver's conversion, so signs, zeros and scales are tested.

Faults, injectable while running: :meth:`silence` (a node's heartbeat and frames stop: cable cut),
:meth:`drop_next` (a TPDO lost), :meth:`error_frames`, :meth:`bus_off` / :meth:`recover`,
:meth:`reboot` (a node resets), ``jitter_s`` (each TPDO delayed by a uniform random time in
[0, jitter_s] s), and the bus clock's faults (they need the wire times below):
:meth:`stamp_next` (one TPDO stamped off the clock: a corrupt timestamp) and :meth:`step_clock`
(every frame from now on stamped off by a constant: the interface's clock was reset or the
system time stepped). The virtual bus has no physical layer, so bus-off is emulated the way a
SocketCAN controller reports it: an error frame with the CAN_ERR_BUSOFF class, then silence.

Timing as on a real bus: a CiA 406 encoder latches its position in hardware at the SYNC and
answers within microseconds; a Python thread may handle the SYNC milliseconds later. So each node
latches the robot's readings at the SYNC's bus time (:meth:`MockRobot.encoder_readings` with
``at``), and, on a virtual bus this object opens, stamps its TPDO with the time it would have
been on the wire: the SYNC's bus time + ``latency_s`` + its jitter delay, as a CAN controller's
receive timestamp would read (python-can's ``preserve_timestamps``). Everything else it sends
is stamped when sent. The driver's attribution of positions to SYNCs is therefore tested against
the device's timing, not against the mock thread's scheduling.

One thread does all the nodes' work; start/stop it with :meth:`start`/:meth:`stop` or ``with``.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import threading
import time
from collections import deque
from types import TracebackType

import can
import numpy as np

from hexcal.drivers.can_config import (
    HEARTBEAT_BASE,
    NMT_COB_ID,
    SYNC_COB_ID,
    CanBusConfig,
)
from hexcal.mock_hw.robot import MockRobot

log = logging.getLogger(__name__)

BOOTUP, STOPPED, OPERATIONAL, PRE_OPERATIONAL = 0x00, 0x04, 0x05, 0x7F
# NMT command specifier -> state entered (resets pass through boot-up, see _nmt).
_NMT_COMMANDS = {0x01: OPERATIONAL, 0x02: STOPPED, 0x80: PRE_OPERATIONAL}
_NMT_RESETS = (0x81, 0x82)

# SocketCAN error classes the emulated faults use (linux/can/error.h).
CAN_ERR_PROT = 0x008
CAN_ERR_BUSOFF = 0x040
CAN_ERR_BUSERROR = 0x080
CAN_ERR_RESTARTED = 0x100

_INT32 = (-(2**31), 2**31 - 1)


class MockEncoderNodes:
    """The six leg encoders of ``config`` answering on ``bus`` (None: open ``config.interface``/
    ``config.channel`` at :meth:`start`, close it at :meth:`stop`).

    ``heartbeat_period_s`` defaults to a quarter of ``config.heartbeat_timeout_s``.
    ``jitter_s``: each TPDO is delayed by U(0, jitter_s) s (0: sent at once). ``seed`` seeds the
    jitter. Observables for tests: ``states`` {leg: NMT state}, ``nmt_log`` [(cs, node)],
    ``history`` [(SYNC counter, readings (6,) mm latched at that SYNC)], the last ``log_len``
    (read it through :meth:`latched` while running), ``syncs_seen``.
    """

    def __init__(
        self,
        robot: MockRobot,
        config: CanBusConfig,
        bus: can.BusABC | None = None,
        *,
        heartbeat_period_s: float | None = None,
        jitter_s: float = 0.0,
        latency_s: float = 100e-6,
        seed: int = 0,
        log_len: int = 1_000,
    ):
        self.robot = robot
        self.config = config
        self.heartbeat_period_s = (
            config.heartbeat_timeout_s / 4 if heartbeat_period_s is None else heartbeat_period_s
        )
        self.jitter_s = jitter_s
        self.latency_s = latency_s
        self._bus_in = bus
        self._bus: can.BusABC | None = None
        self._wire_times = False
        self._rng = np.random.default_rng(seed)
        self._lock = threading.Lock()
        self._send_lock = threading.RLock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._node_ids = [c.node_id for c in config.legs]
        self._leg_of_node = {c.node_id: c.leg for c in config.legs}
        self.states: dict[int, int] = dict.fromkeys(range(1, 7), BOOTUP)
        self._silent = dict.fromkeys(range(1, 7), False)
        self._drop = dict.fromkeys(range(1, 7), 0)
        self._skew_next: dict[int, float] = {}  # leg -> s added to its next TPDO's stamp
        self._clock_step_s = 0.0  # s added to every stamp (the interface's clock jumped)
        self._bus_off = False
        self._scheduled: list[tuple[float, int, can.Message]] = []
        self._seq = itertools.count()
        self.nmt_log: list[tuple[int, int]] = []
        self.history: deque[tuple[int, np.ndarray]] = deque(maxlen=log_len)
        self.syncs_seen = 0

    # -- lifecycle -------------------------------------------------------------------------------
    def start(self) -> MockEncoderNodes:
        """Open the bus (if not given), send the six boot-ups and start answering."""
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
        for leg in range(1, 7):
            self.states[leg] = PRE_OPERATIONAL
            self._heartbeat(leg, BOOTUP)
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
        if self._bus_in is None and self._bus is not None:
            self._bus.shutdown()
        self._bus = None

    def __enter__(self) -> MockEncoderNodes:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    def latched(self) -> dict[int, np.ndarray]:
        """{SYNC counter: readings (6,) mm latched at that SYNC}, a snapshot (the latest SYNC
        wins when the 1..240 counter wraps)."""
        with self._lock:
            return {c: r.copy() for c, r in self.history}

    # -- fault injection -------------------------------------------------------------------------
    def silence(self, leg: int, silent: bool = True) -> None:
        """Leg ``leg``'s node goes quiet (no heartbeat, no TPDO, deaf to NMT) — or comes back,
        keeping its NMT state, as after a reconnected cable."""
        with self._lock:
            self._silent[leg] = silent

    def drop_next(self, leg: int, n: int = 1) -> None:
        """Lose the next ``n`` TPDOs of leg ``leg`` (the SYNCs still happen)."""
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

    def reboot(self, leg: int) -> None:
        """Leg ``leg``'s node resets: boot-up message, then PRE-OPERATIONAL (no TPDOs)."""
        with self._lock:
            self.states[leg] = PRE_OPERATIONAL
        self._heartbeat(leg, BOOTUP)

    # -- the nodes' work -------------------------------------------------------------------------
    def _send(self, msg: can.Message) -> None:
        bus = self._bus
        if bus is None:
            return
        with self._send_lock:
            if self._bus_off and not msg.is_error_frame:
                return  # decided before bus_off(), sent after: a bus-off controller sends nothing
            if self._wire_times:
                msg.timestamp = (msg.timestamp or time.time()) + self._clock_step_s
            try:
                bus.send(msg)
            except can.CanError as exc:  # a mock must not die on a full queue: log and go on
                log.warning("mock encoders could not send %s: %s", msg, exc)

    def _heartbeat(self, leg: int, state: int | None = None) -> None:
        with self._lock:
            if self._silent[leg] or self._bus_off:
                return
            st = self.states[leg] if state is None else state
        node = self.config.leg(leg).node_id
        self._send(
            can.Message(arbitration_id=HEARTBEAT_BASE + node, data=[st], is_extended_id=False)
        )

    def _run(self) -> None:
        bus = self._bus
        assert bus is not None
        next_hb = time.monotonic() + self.heartbeat_period_s
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_hb:
                for leg in range(1, 7):
                    self._heartbeat(leg)
                next_hb += self.heartbeat_period_s
                if now - next_hb > self.heartbeat_period_s:  # stalled: do not burst
                    next_hb = now + self.heartbeat_period_s
            self._send_due(now)
            with self._lock:
                due = self._scheduled[0][0] if self._scheduled else next_hb
            timeout = min(max(0.0, min(due, next_hb) - time.monotonic()), 0.05)
            try:
                msg = bus.recv(timeout)
            except can.CanError:  # bus closed under us at shutdown
                break
            if msg is None or msg.is_error_frame or msg.is_extended_id:
                continue
            if msg.arbitration_id == SYNC_COB_ID:
                self._on_sync(msg)
            elif msg.arbitration_id == NMT_COB_ID and len(msg.data) >= 2:
                self._on_nmt(msg.data[0], msg.data[1])

    def _send_due(self, now: float) -> None:
        while True:
            with self._lock:
                if not self._scheduled or self._scheduled[0][0] > now:
                    return
                _, _, msg = heapq.heappop(self._scheduled)
            self._send(msg)

    def _on_nmt(self, cs: int, node: int) -> None:
        self.nmt_log.append((cs, node))
        changed = []
        with self._lock:
            for nid in self._node_ids if node == 0 else [node]:
                leg = self._leg_of_node.get(nid)
                if leg is None or self._silent[leg] or self._bus_off:
                    continue
                if cs in _NMT_RESETS:
                    self.states[leg] = PRE_OPERATIONAL
                    changed.append((leg, BOOTUP))
                elif cs in _NMT_COMMANDS:
                    self.states[leg] = _NMT_COMMANDS[cs]
                    changed.append((leg, None))
        for leg, state in changed:  # answer at once: the master need not wait a heartbeat period
            self._heartbeat(leg, state)

    def _on_sync(self, msg: can.Message) -> None:
        counter = msg.data[0] if len(msg.data) >= 1 else 0
        t = time.monotonic()
        # The SYNC's bus time (wall clock on python-can's buses) on the monotonic clock.
        t_bus = msg.timestamp or time.time()
        t_sync = t_bus - (time.time() - t)
        at = t_sync if self.robot.clock is time.monotonic and t_sync <= t else None
        readings = self.robot.encoder_readings(at)  # latched at the SYNC, as a CiA 406 encoder does
        out: list[tuple[float, can.Message]] = []
        with self._lock:
            self.syncs_seen += 1
            self.history.append((counter, readings))
            if self._bus_off:
                return
            for cfg in self.config.legs:
                leg = cfg.leg
                if self._silent[leg] or self.states[leg] != OPERATIONAL:
                    continue
                if self._drop[leg] > 0:
                    self._drop[leg] -= 1
                    continue
                counts = min(max(cfg.mm_to_counts(float(readings[leg - 1])), _INT32[0]), _INT32[1])
                delay = float(self._rng.uniform(0.0, self.jitter_s)) if self.jitter_s > 0 else 0.0
                skew = self._skew_next.pop(leg, 0.0)
                frame = can.Message(
                    arbitration_id=cfg.tpdo1_cob_id,
                    data=counts.to_bytes(4, "little", signed=True),
                    is_extended_id=False,
                    # Never later than now (+ its delay): a wire time is never in the future.
                    timestamp=min(t_bus + self.latency_s, time.time()) + delay + skew
                    if self._wire_times
                    else 0.0,
                )
                out.append((delay, frame))
            for delay, frame in out:
                if delay > 0:
                    heapq.heappush(self._scheduled, (t + delay, next(self._seq), frame))
        for delay, frame in out:
            if delay == 0:
                self._send(frame)


__all__ = ["MockEncoderNodes"]
