"""The receive path of :class:`~hexcal.drivers.can_encoders.LegEncoders`: every frame the bus
brings, placed on the bus clock (:class:`~hexcal.drivers.can_clock.BusClock`) and handled —
positions attributed to the SYNC that latched them, SYNCs seen on the bus, EMCY, heartbeats
(through canopen's NMT master), error frames — and the reading sets assembled and closed.

:class:`_ReceivePath` is a base class of ``LegEncoders``, not a class of its own: it works on
the driver's state (set up in ``LegEncoders.__init__`` and ``_reset_run``, guarded by its
``_lock``) and uses the driver's messages (``_note``, ``_age``, ``_silent_message``,
``_bus_message``) and ``_nmt_start``. The attribution rules are in that module's docstring.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from typing import TYPE_CHECKING

import can
import numpy as np
from canopen.nmt import NMT_STATES

from hexcal.drivers.can_config import SYNC_COB_ID
from hexcal.drivers.can_emcy import Emergency
from hexcal.drivers.can_frames import (
    BUS_ACTIVE,
    BUS_ERROR,
    BUS_OFF,
    BUS_PASSIVE,
    CAN_ERR_BUSOFF,
    CAN_ERR_CRTL,
    CAN_ERR_CRTL_ACTIVE,
    CAN_ERR_CRTL_RX_PASSIVE,
    CAN_ERR_CRTL_TX_PASSIVE,
    CAN_ERR_RESTARTED,
    NMT_BOOTUP,
    NMT_OPERATIONAL,
    NMT_PRE_OPERATIONAL,
    ReadingSet,
    _nonfinite_message,
    _short_tpdo_message,
    describe_error_frame,
)
from hexcal.drivers.can_nodes import EncoderConfigError, configure_node

if TYPE_CHECKING:
    from collections import deque

    from hexcal.drivers.can_clock import BusClock
    from hexcal.drivers.can_config import CanBusConfig
    from hexcal.drivers.can_frames import TpdoDecoder
    from hexcal.drivers.can_network import Network, Recorder
    from hexcal.drivers.can_nodes import NodeInfo

# The driver's logger: these messages were always logged as hexcal.drivers.can_encoders's, and
# operators and tests select them by that name.
log = logging.getLogger("hexcal.drivers.can_encoders")


class _Pending:
    """A set being assembled (plain lists: faster per frame than numpy element writes)."""

    __slots__ = (
        "arrival",
        "counter",
        "echoed",
        "faults",
        "index",
        "n",
        "readings",
        "stamps",
        "t_bus",
        "t_bus_hi",
        "t_sync",
    )

    def __init__(
        self,
        index: int,
        counter: int,
        t_sync: float,
        t_bus: float,
        faults: dict[str, str],
        t_bus_hi: float | None = None,
    ):
        self.index = index
        self.counter = counter
        self.t_sync = t_sync  # monotonic s
        self.t_bus = t_bus  # the same instant on the bus interface's clock, s
        # The latest bus time the SYNC can have been on the wire (s): t_bus for a SYNC seen on
        # the bus; for the driver's own, stamped before sending, inf until the send returned or
        # its echo came (see _confirm_sync).
        self.t_bus_hi = t_bus if t_bus_hi is None else t_bus_hi
        self.echoed = False
        self.readings = [math.nan] * 6
        self.stamps = [math.nan] * 6  # each position's bus time, s
        self.arrival = [math.nan] * 6  # the same on the monotonic clock, s (set on closing)
        self.n = 0
        self.faults = faults  # key -> message; a key repeats (error frames) without piling up

    @property
    def t_sent(self) -> float:
        """Monotonic s by which the SYNC was on the wire (inf while the driver is sending it)."""
        return self.t_sync + (self.t_bus_hi - self.t_bus)


def _sync_counter(msg: can.Message) -> int:
    """A SYNC's counter byte (0 for a SYNC without one)."""
    return msg.data[0] if len(msg.data) >= 1 else 0


class _ReceivePath:
    """Frame handling and set assembly of :class:`~hexcal.drivers.can_encoders.LegEncoders`
    (module docstring)."""

    # The driver's state this path works on: set by LegEncoders (its __init__ and resets);
    # declared here so that the type checker holds both halves to one set of names and types.
    config: CanBusConfig
    decoder: TpdoDecoder
    listen_only: bool
    max_queue: int
    nodes: list[NodeInfo]
    _lock: threading.Lock
    _cond: threading.Condition
    _stop_evt: threading.Event
    _clock: BusClock
    _network: Network | None
    _recorder: Recorder | None
    _open: deque[_Pending]
    _queue: deque[ReadingSet]
    _latest: ReadingSet | None
    _pending_faults: dict[str, str]
    _bus_name: str
    _names: list[str]
    _deadline: float
    _producing: bool
    _running: bool
    _configuring: set[int]
    _leg_of_emcy: dict[int, int]
    _emergencies: list[Emergency | None]
    _emcy_count: int
    _index: int
    _evidence: float
    _position_arrived: float
    _last_closed_t_bus: float
    _incomplete: int
    _discarded: int
    _late_discarded: int
    _foreign_syncs: int
    _own_syncs: deque[_Pending]
    _eds_cache: dict[tuple[int, ...], bytes]
    _echo_marked: bool
    _error_frames: int
    _bus_state: str
    _bus_detail: str
    _last_hb: list[float | None]
    _hb_state: list[int | None]
    _silent: list[bool]
    _last_nmt: list[float]
    _frames: list[int]
    _missing: list[int]
    _reboots: list[int]

    # Defined by LegEncoders (messages and sending); the receive path calls them.
    def _age(self, k: int, now: float) -> float:
        raise NotImplementedError

    def _silent_message(self, k: int, now: float) -> str:
        raise NotImplementedError

    def _bus_message(self) -> str:
        raise NotImplementedError

    def _note(self, key: str, message: str) -> None:
        raise NotImplementedError

    def _nmt_start(self, k: int) -> None:
        raise NotImplementedError

    # -- the bus clock (lock held) -----------------------------------------------------------------
    def _bus_time(self, msg: can.Message, t: float) -> tuple[float, bool]:
        """The frame's bus time (s on the interface's clock) and whether it is trusted; the
        clock learns its offset and follows its jumps (:mod:`hexcal.drivers.can_clock`). ``t``
        is the frame's monotonic arrival time. Lock held."""
        ts, trusted, shift = self._clock.place(msg.timestamp, t)
        if shift is not None:
            self._reanchor(shift)
        return ts, trusted

    def _reanchor(self, shift: float) -> None:
        """The bus clock jumped by ``shift`` s (a bus time on the old clock + shift = the same
        instant on the new): move the open sets and the closing evidence onto the new clock."""
        for s in self._open:
            s.t_bus += shift
            s.t_bus_hi += shift
            s.stamps = [ts + shift for ts in s.stamps]
        self._evidence += shift
        self._last_closed_t_bus += shift
        message = (
            f"the clock of {self._bus_name} jumped {shift:+.3f} s (frame timestamps against the "
            "host clock: the interface's clock was reset or the system time stepped) — SYNC "
            "attribution re-anchored to the new clock; sets around the jump are flagged"
        )
        log.warning("%s", message)
        self._note("clock_jump", message)

    # -- assembling sets (lock held) --------------------------------------------------------------
    def _open_set(
        self, t: float, t_bus: float, counter: int, t_bus_hi: float | None = None
    ) -> _Pending:
        faults, self._pending_faults = self._pending_faults, {}
        for k, em in enumerate(self._emergencies):
            if em is not None:  # the node still reports an error: its readings are suspect
                faults[f"emcy{k}"] = em.describe(self._names[k])
        s = _Pending(self._index, counter, t, t_bus, faults, t_bus_hi)
        self._open.append(s)
        self._index += 1
        return s

    def _confirm_sync(self, counter: int, ts: float) -> bool:
        """A SYNC on the wire at bus time ``ts`` (counter byte ``counter``, 0 without one) that
        may be the echo of one the driver sent: True when it is, and the set that SYNC opened
        then has its exact SYNC time. Echoes come in the order sent; the recent sends are kept
        (``_own_syncs``), so an echo handled after its set closed is still told for what it is.
        Between the host's two stamps, give or take half the answer deadline for the clocks'
        offset: the next SYNC goes a whole deadline after this one's send returned."""
        margin = self._deadline / 2
        for s in self._own_syncs:
            if s.echoed or (counter and s.counter != counter):
                continue
            if not s.t_bus - margin <= ts <= s.t_bus_hi + margin:
                continue
            s.t_sync += ts - s.t_bus
            s.t_bus = s.t_bus_hi = ts
            s.echoed = True
            return True
        return False

    def _close_until(self, evidence: float) -> None:
        """Close the open sets whose answers are all due before bus time ``evidence``."""
        self._evidence = max(self._evidence, evidence)
        while self._open and self._open[0].t_bus_hi + self._deadline < self._evidence:
            self._close(time.monotonic())

    def _close_all(self) -> None:
        """Close every open set now (the SYNC just opened could not be sent)."""
        while self._open:
            self._close(time.monotonic())

    def _close(self, now: float) -> None:
        """Close the oldest open set and queue it."""
        s = self._open.popleft()
        self._last_closed_t_bus = s.t_bus
        cfg = self.config
        bus_down = self._bus_state != BUS_ACTIVE
        for k in range(6):
            ts = s.stamps[k]
            if ts == ts:
                s.arrival[k] = s.t_sync + (ts - s.t_bus)
                # Judged now, against the SYNC's time as finally known: the driver's own SYNC
                # may have gone on the wire well after it was stamped (a busy host).
                delay = ts - s.t_bus_hi
                if delay > self._deadline:
                    s.faults[f"late{k}"] = (
                        f"{self._names[k]} position arrived {delay * 1e3:.1f} ms after SYNC "
                        f"{s.counter} (limit {self._deadline * 1e3:.1f} ms) on {self._bus_name}: "
                        "timing jitter or bus overload — set flagged; if it repeats reduce the bus "
                        "load or raise max_tpdo_delay_s"
                    )
            # The cause (a silent node, a node not started, the bus down) is reported instead
            # of its symptom, the missing position, so the operator reads what to fix.
            cause = False
            if self._age(k, now) > cfg.heartbeat_timeout_s:
                s.faults[f"silent{k}"] = self._silent_message(k, now)
                cause = True
            st = self._hb_state[k]
            if st is not None and st != NMT_OPERATIONAL:
                cause = True
                s.faults[f"nmt{k}"] = (
                    f"{self._names[k]} reports NMT state {NMT_STATES.get(st, hex(st))} on "
                    f"{self._bus_name}, not OPERATIONAL, so it sends no position — "
                    + (
                        "it may have rebooted (supply dip?); hexcal sent NMT start again, check its "
                        "power if this repeats"
                        if not self.listen_only
                        else "the NMT master must start it"
                    )
                )
            if s.arrival[k] != s.arrival[k]:  # NaN: no position for this SYNC
                self._missing[k] += 1
                if not (cause or bus_down):
                    s.faults.setdefault(
                        f"missing{k}",
                        f"{self._names[k]} sent no position for SYNC {s.counter} on {self._bus_name}: "
                        "frame lost or late — set flagged incomplete; if it repeats check that node's "
                        "cable and the bus termination",
                    )
        if bus_down:
            s.faults["bus"] = self._bus_message()
        complete = s.n == 6 and not s.faults
        rs = ReadingSet(
            sync_counter=s.counter,
            t_sync=s.t_sync,
            readings_mm=np.array(s.readings),
            arrival=np.array(s.arrival),
            complete=complete,
            faults=list(s.faults.values()),
            index=s.index,
            reboots=tuple(self._reboots),
        )
        if not complete:
            self._incomplete += 1
        if len(self._queue) >= self.max_queue:
            self._queue.popleft()
            self._discarded += 1
            self._pending_faults["discarded"] = (
                f"{self._discarded} reading sets from {self._bus_name} were discarded unread (queue "
                f"of {self.max_queue} full) — call read_set()/sample() continuously; the CAN log "
                "keeps every frame"
            )
        self._queue.append(rs)
        self._latest = rs
        self._cond.notify_all()

    # -- receive thread ---------------------------------------------------------------------------
    def _on_message(self, msg: can.Message) -> None:
        t = time.monotonic()  # stamped on arrival, before anything else
        rec = self._recorder
        if rec is not None:
            with rec.lock:  # held across both: the log keeps the order the driver saw
                own = self._dispatch(msg, t)
                if msg.is_rx and not own:  # an echo of our own frame was logged when it was sent
                    rec.write(msg)
        else:
            self._dispatch(msg, t)

    def _dispatch(self, msg: can.Message, t: float) -> bool:
        """Handle one frame; True when it is the echo of the driver's own SYNC."""
        if not msg.is_rx:
            self._on_own_frame(msg, t)
            return True
        with self._lock:
            ts, trusted = self._bus_time(msg, t)
        if msg.is_error_frame:
            self._on_error_frame(msg, t)
            return False
        if msg.is_remote_frame or msg.is_extended_id:
            return False
        cid = msg.arbitration_id
        entry = self.decoder.table.get(cid)
        if entry is not None:
            self._position_arrived = t
            if trusted:
                self._on_tpdo(entry, msg.data, ts)
            else:
                self._on_unplaced_tpdo(entry[0] - 1, t - ts)
        elif cid == SYNC_COB_ID:
            if self._on_bus_sync(msg, t, ts if trusted else None):
                return True
        elif cid in self._leg_of_emcy:
            self._on_emcy(self._leg_of_emcy[cid], msg.data, ts if trusted else None)
        # Only positions close sets: a later position (bus time) shows the earlier SYNCs'
        # answers are all in. Other frames may come from other senders' queues: the echo of
        # hexcal's own SYNC is queued when sent, a node's heartbeat by its own timer, so where
        # frames are not queued in wire order (a virtual bus, simulated nodes on a busy host)
        # they can arrive before answers that were on the bus in time.
        if trusted and entry is not None:  # an untrusted bus time must not close sets either
            with self._lock:
                self._close_until(ts)
        if self._bus_state == BUS_OFF:
            with self._lock:
                # A frame from another node came through: the controller is receiving again.
                self._bus_state, self._bus_detail = BUS_ACTIVE, ""
                self._note(
                    "recovered",
                    f"{self._bus_name} recovered from BUS-OFF (frames arrive again); sets taken "
                    "while it was off are flagged",
                )
        return False

    def _on_own_frame(self, msg: can.Message, t: float) -> None:
        """The echo of a frame this driver sent (``receive_own_messages``): only a SYNC's is
        used, for its wire time. It is read on the bus clock but teaches the clock nothing: its
        stamp comes from the sending side, which an emulated interface may stamp differently."""
        if msg.arbitration_id != SYNC_COB_ID or msg.is_error_frame or not self._producing:
            return
        with self._lock:
            ts = self._clock.peek(msg.timestamp, t)
            if ts is not None:
                self._confirm_sync(_sync_counter(msg), ts)

    def _on_tpdo(self, entry: tuple[int, int, float, float], data: bytearray, ts: float) -> None:
        """A position stamped ``ts`` on the bus clock."""
        leg, sign, cpm, zero = entry
        k = leg - 1
        with self._lock:
            self._frames[k] += 1
            if len(data) < 4:
                self._note(
                    f"short{k}", _short_tpdo_message(self.config.legs[k], len(data), self.config)
                )
                return
            counts = self.decoder.counts(k, data)
            mm = sign * counts / cpm + zero
            s = next((o for o in reversed(self._open) if o.t_bus <= ts), None)
            if not math.isfinite(mm):  # a fault of that set, never a reading
                target = s.faults if s is not None else self._pending_faults
                target[f"nonfinite{k}"] = _nonfinite_message(
                    self.config.legs[k], counts, self.config
                )
                return
            if s is None:
                if ts >= self._last_closed_t_bus:
                    # Its SYNC's set was closed already (flagged with this position missing).
                    self._late_discarded += 1
                    log.debug("%s: position after its set closed, discarded", self._names[k])
                    return
                self._note(
                    f"orphan{k}",
                    f"{self._names[k]} sent a position ({mm:.4f} mm) outside any SYNC window on "
                    f"{self._bus_name} (very late, or TPDO{self.config.tpdo} not synchronous) — "
                    f"discarded; check its TPDO{self.config.tpdo} transmission type is 1 (every "
                    "SYNC: hexcal sets it when can.configure is true)",
                )
                return
            if s.stamps[k] == s.stamps[k]:
                s.faults[f"twice{k}"] = (
                    f"{self._names[k]} sent two positions for SYNC {s.counter} on {self._bus_name} (a "
                    "late frame from the previous SYNC, or a cyclic TPDO?) — set flagged, the later "
                    f"one kept; check its TPDO{self.config.tpdo} transmission type is 1 (every SYNC)"
                )
            else:
                s.n += 1
            s.readings[k] = mm
            s.stamps[k] = ts
            self._cond.notify_all()  # stop() waits for the last set's answers

    def _on_unplaced_tpdo(self, k: int, lag: float) -> None:
        """A position whose bus time is not trusted (it arrived ``lag`` s after it): no SYNC
        window can be told for it, so it is discarded and the newest set flagged."""
        with self._lock:
            self._frames[k] += 1
            off = self._clock.offset - lag
            self._note(
                f"stamp{k}",
                f"{self._names[k]} sent a position stamped {off:+.3f} s off the clock of "
                f"{self._bus_name} (against the host clock) — no SYNC can be told for it, so it "
                "was discarded and this set flagged; a jump of the interface's clock or a corrupt "
                "timestamp",
            )

    def _on_bus_sync(self, msg: can.Message, t: float, ts: float | None) -> bool:
        """A SYNC on the bus at bus time ``ts`` (None: not trusted, placed by arrival ``t``);
        True when it is the driver's own SYNC come back (an interface that does not mark
        echoes)."""
        counter = _sync_counter(msg)
        with self._lock:
            if self._producing:
                # An interface that cannot mark echoes (python-can's udp_multicast loops every
                # frame back as received) returns the driver's own SYNC as if another node had
                # sent it: one that fits a SYNC just sent is that SYNC, not another producer's.
                if not self._echo_marked and self._confirm_sync(
                    counter, self._clock.to_bus(t) if ts is None else ts
                ):
                    return True
                self._foreign_syncs += 1
                self._note(
                    "foreign_sync",
                    f"another SYNC producer is on {self._bus_name} (SYNC not sent by hexcal) — "
                    "the encoders answer both; switch it off, or set sync_period_s = 0 to follow it",
                )
                return False
            if ts is None:
                self._open_set(t, self._clock.to_bus(t), counter)
                self._open[-1].faults["sync_stamp"] = (
                    f"SYNC {counter} on {self._bus_name} carried a timestamp off the bus clock: "
                    "placed by its arrival instead, so its positions may be misplaced — set flagged"
                )
                return False
            self._open_set(ts + self._clock.offset, ts, counter)
        return False

    def _on_emcy(self, k: int, data: bytearray, ts: float | None) -> None:
        """An EMCY of leg ``k + 1``'s node at bus time ``ts`` (None: not trusted): it flags the
        set it falls in, and the sets after it while the node's error register is non-zero."""
        em = Emergency.from_frame(self.config.legs[k].node_id, bytes(data))
        with self._lock:
            self._emcy_count += 1
            if em.is_reset:
                if self._emergencies[k] is not None:
                    log.info("%s: error reset (EMCY 0x0000)", self._names[k])
                self._emergencies[k] = None
                return
            text = em.describe(self._names[k])
            log.warning("%s on %s", text, self._bus_name)
            self._emergencies[k] = em if em.register else None
            s = (
                next((o for o in reversed(self._open) if o.t_bus <= ts), None)
                if ts is not None
                else None
            )
            target = (
                s.faults
                if s is not None
                else (self._open[-1].faults if self._open else self._pending_faults)
            )
            target[f"emcy{k}"] = text

    def _on_heartbeat(self, k: int, state: int) -> None:
        """A heartbeat of leg ``k + 1``'s node (through canopen's NMT master), NMT ``state``."""
        t = time.monotonic()
        restart = False
        with self._lock:
            self._last_hb[k] = t
            self._hb_state[k] = state
            if self._silent[k]:
                self._silent[k] = False
                log.info("%s heartbeat back on %s", self._names[k], self._bus_name)
            if state == NMT_BOOTUP and self._running:
                self._reboots[k] += 1
                self._note(
                    f"bootup{k}",
                    f"{self._names[k]} rebooted (boot-up message on {self._bus_name}) — "
                    + ("hexcal sets it up and starts it again; " if not self.listen_only else "")
                    + "check its supply if this repeats",
                )
            reboot = state == NMT_BOOTUP and self.config.configure
            if (
                self._running
                and not self.listen_only
                and k not in self._configuring
                and state in (NMT_BOOTUP, NMT_PRE_OPERATIONAL)
                and (reboot or t - self._last_nmt[k] > self.config.heartbeat_timeout_s / 5)
            ):
                restart = True
                if reboot:
                    self._configuring.add(k)
            self._cond.notify_all()
        if not restart:
            return
        if reboot:
            # A rebooted node is back at its factory settings (no heartbeat, no synchronous
            # position). SDO answers come through this very thread, so set it up from another.
            threading.Thread(
                target=self._reconfigure, args=(k,), name="hexcal-can-reconfigure", daemon=True
            ).start()
        else:  # outside the lock: sending may block
            self._nmt_start(k)

    def _reconfigure(self, k: int) -> None:
        """Set leg ``k + 1``'s node up again after a reboot, then NMT-start it."""
        net = self._network
        try:
            if net is None:
                return
            info = configure_node(net, self.config.legs[k], self.config, self._eds_cache)
            with self._lock:
                if self.nodes:
                    self.nodes[k] = info
            self._nmt_start(k)
        except EncoderConfigError as exc:
            with self._lock:
                self._note(f"reconfigure{k}", str(exc))
        finally:
            with self._lock:
                self._configuring.discard(k)

    def _on_error_frame(self, msg: can.Message, t: float) -> None:
        cls = msg.arbitration_id & 0x1FFFFFFF
        desc = describe_error_frame(msg)
        with self._lock:
            self._error_frames += 1
            if cls & CAN_ERR_BUSOFF:
                if self._bus_state != BUS_OFF:
                    log.error("%s is BUS-OFF", self._bus_name)
                self._bus_state, self._bus_detail = BUS_OFF, "error frame: bus-off"
            elif cls & CAN_ERR_RESTARTED:
                self._bus_state, self._bus_detail = BUS_ACTIVE, ""
            elif cls & CAN_ERR_CRTL and len(msg.data) > 1:
                ctrl = msg.data[1]
                if ctrl & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE):
                    self._bus_state, self._bus_detail = BUS_PASSIVE, "error frame: " + desc
                elif ctrl & CAN_ERR_CRTL_ACTIVE:
                    self._bus_state, self._bus_detail = BUS_ACTIVE, ""
            self._note(
                "error_frame",
                f"CAN error frame on {self._bus_name} ({desc}; {self._error_frames} so far): frames "
                "are being corrupted — check the 120 Ω termination at both ends, the connectors and "
                f"that every node runs at {self.config.bitrate / 1000:g} kbit/s",
            )

    def _on_receive_error(self, exc: Exception) -> None:
        with self._lock:
            self._bus_state, self._bus_detail = BUS_ERROR, f"receive failed: {exc}"
            self._note("receive", self._bus_message())
        # The notifier retries at once; do not spin on a dead adapter.
        self._stop_evt.wait(0.05)
