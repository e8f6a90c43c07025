"""The six CANopen (CiA 406) leg encoders, read through python-can and the ``canopen`` package.

On the wire (CiA 301 predefined connection set):

- at start, each node is put in PRE-OPERATIONAL (NMT ``0x000 [0x80, node]``) and set up over SDO
  (:mod:`hexcal.drivers.can_nodes`: device type and identity checked, 0x6004 mapped into TPDO
  ``tpdo`` — 2 by default, CiA 406's synchronous one — on every SYNC, the heartbeat producer
  time written, the SYNC counter as the nodes expect); then NMT start ``[0x01, node]``;
- the driver (or another master) sends SYNC ``0x080`` (with a counter byte only when the nodes'
  0x1019 asks for one); every encoder latches its position and answers with its TPDO
  ``0x280 + node``, bytes 0..3 = object 0x6004 (INTEGER32 or UNSIGNED32 counts as the object
  dictionary says, little endian; an UNSIGNED32 position wraps at the total measuring range
  0x6002 and is unwrapped here);
- every node sends a heartbeat ``0x700 + node [state]`` at its producer period (0x1017),
  received through ``canopen``'s NMT master;
- an encoder in trouble sends EMCY ``0x080 + node``: it flags the set it falls in (by bus time)
  and every set while the node's error register stays non-zero, with the code's meaning.

With ``configure = false`` the nodes are taken as set up already and only NMT-started.

Why positions are not received through ``canopen``'s PDO callbacks: attribution to a SYNC needs
each frame's bus time *and* its arrival on the host, taken before anything else handles it
(below); canopen's callbacks give the first but not the second. The PDO itself is configured
through canopen's PDO maps and decoded with the data type its object dictionary gives.

A *reading set* is the six positions answering one SYNC. Every frame carries the time the bus
interface stamped it (``msg.timestamp``: the kernel's receive time on SocketCAN, the send time
on python-can's virtual bus, hardware time on many adapters); frames without one are stamped on
arrival. A position is attributed to the latest SYNC that went on the bus before it, by those
bus times — not to whatever set is open when the receive thread gets round to it, so a busy
computer that handles frames late cannot shift a position into the wrong set. The driver's own
SYNC goes on the wire some time between two host stamps, taken before sending and once the send
returned (put on the bus clock by the offset between the two clocks: the smallest arrival − bus
time seen over the last few seconds); a busy host can stall the sender in between. Its echo
(the bus is opened with ``receive_own_messages``: SocketCAN's loopback, the virtual bus) gives
the wire time itself; without one, positions are placed after the first stamp and judged late
against the second. Where echoes come unmarked (``udp_multicast``), a SYNC that fits one just
sent is its echo, not another producer's (:meth:`_ReceivePath._confirm_sync`). Several sets may
be open at once; a set closes once a frame stamped more than ``tpdo_deadline_s`` after its SYNC
has been handled (frames on one bus arrive in order, so nothing in time for it can still come),
or, when the bus goes quiet, ``close_after`` after its SYNC. A position for a set already closed
is discarded (that set was flagged with the position missing); two positions from one node for
one SYNC flag the set. Produced SYNCs are kept at least ``tpdo_deadline_s`` apart, so after a
stall no catch-up SYNC can overtake the answers to the one before.

Clock jumps (an adapter that resets, a stepped system time, a corrupt timestamp) are followed
by :class:`~hexcal.drivers.can_clock.BusClock`; its module docstring says how. A frame whose bus
time is not trusted takes no part in attribution, and a position it carries is discarded and its
set flagged.

Anything unusual during a set — a position missing, late or twice, a silent node, a node not
OPERATIONAL, a CAN error frame, the bus not error-active, a SYNC that could not be sent — is
written into that set's ``faults`` and the set is not ``complete``. No set is dropped: every
SYNC gives exactly one set, in order, numbered by ``index``. The raw traffic can be written to
a python-can log (``log_path``: .asc, .blf, .csv, .log, ...) and replayed later through
:class:`LegEncoders` in ``listen_only`` mode.

Known limit: a node that answers every SYNC more than a whole period late (a broken node) looks
on the bus like one that answers on time, one SYNC behind; only its first, missing position is
flagged. Real CiA 406 encoders latch in hardware at the SYNC and answer within microseconds.

Where the parts live: frame decoding, reading sets, bus states and the errors in
:mod:`hexcal.drivers.can_frames` (re-exported here), the bus clock in
:mod:`hexcal.drivers.can_clock`, the receive path (frame handling, set assembly) in
:mod:`hexcal.drivers.can_receive`; :class:`LegEncoders` here holds the lifecycle, the reading
API, the SYNC producer and the supervision.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import math
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

import can
from canopen.nmt import NMT_STATES

from hexcal.acquire.acquisition import LegSample
from hexcal.drivers.base import Device
from hexcal.drivers.can_clock import BusClock
from hexcal.drivers.can_config import CanBusConfig
from hexcal.drivers.can_emcy import Emergency
from hexcal.drivers.can_frames import (
    BUS_ACTIVE,
    BUS_ERROR,
    BUS_OFF,
    BUS_PASSIVE,
    NMT_CMD_PRE_OPERATIONAL,
    NMT_CMD_START,
    NMT_OPERATIONAL,
    SYNC_COUNTER_MAX,
    BusError,
    EncoderError,
    EncoderSilent,
    ReadingSet,
    TpdoDecoder,
)
from hexcal.drivers.can_frames import CAN_ERR_ACK as CAN_ERR_ACK
from hexcal.drivers.can_frames import CAN_ERR_BUSERROR as CAN_ERR_BUSERROR
from hexcal.drivers.can_frames import CAN_ERR_BUSOFF as CAN_ERR_BUSOFF
from hexcal.drivers.can_frames import CAN_ERR_CRTL as CAN_ERR_CRTL
from hexcal.drivers.can_frames import CAN_ERR_CRTL_ACTIVE as CAN_ERR_CRTL_ACTIVE
from hexcal.drivers.can_frames import CAN_ERR_CRTL_RX_PASSIVE as CAN_ERR_CRTL_RX_PASSIVE
from hexcal.drivers.can_frames import CAN_ERR_CRTL_TX_PASSIVE as CAN_ERR_CRTL_TX_PASSIVE
from hexcal.drivers.can_frames import CAN_ERR_LOSTARB as CAN_ERR_LOSTARB
from hexcal.drivers.can_frames import CAN_ERR_PROT as CAN_ERR_PROT
from hexcal.drivers.can_frames import CAN_ERR_RESTARTED as CAN_ERR_RESTARTED
from hexcal.drivers.can_frames import CAN_ERR_TRX as CAN_ERR_TRX
from hexcal.drivers.can_frames import CAN_ERR_TX_TIMEOUT as CAN_ERR_TX_TIMEOUT
from hexcal.drivers.can_frames import NMT_BOOTUP as NMT_BOOTUP
from hexcal.drivers.can_frames import NMT_PRE_OPERATIONAL as NMT_PRE_OPERATIONAL
from hexcal.drivers.can_frames import decode_tpdo as decode_tpdo
from hexcal.drivers.can_frames import describe_error_frame as describe_error_frame
from hexcal.drivers.can_network import Listener, Network, Recorder
from hexcal.drivers.can_nodes import EncoderConfigError, NodeInfo, configure_node, eds_for
from hexcal.drivers.can_receive import _Pending, _ReceivePath
from hexcal.drivers.limits import check_duration

log = logging.getLogger(__name__)


# -- the driver ------------------------------------------------------------------------------------
class LegEncoders(_ReceivePath, Device):
    """The six leg encoders on one CAN bus.

    ``config``: bus and legs. ``bus``: an open python-can bus to use (the caller keeps owning
    it); None opens ``config.interface``/``config.channel`` at :meth:`start` and closes it at
    :meth:`stop`. ``listen_only``: send nothing (no NMT, no SYNC) and decode what is on the bus —
    for sniffing a bus another master runs, or replaying a log. ``log_path``: write every frame
    received and sent to this python-can log (.asc, .blf, ...). ``max_queue``: reading sets kept
    for :meth:`read_set` (100 000 ≈ 17 min at 100 Hz); beyond it the oldest are discarded and the
    next set says so. ``clock_jump_s``: how far (s) a frame's bus time may stray from the learnt
    bus-to-host clock offset before it is taken for a clock jump (:mod:`~hexcal.drivers.can_clock`). The
    configuration's durations must be at most :data:`~hexcal.drivers.limits.MAX_TIMEOUT_S`
    (ValueError naming the field otherwise).

    Implements the acquisition's ``LegSource`` (:meth:`sample`). A context manager.
    """

    def __init__(
        self,
        config: CanBusConfig,
        bus: can.BusABC | None = None,
        *,
        listen_only: bool = False,
        log_path: str | Path | None = None,
        max_queue: int = 100_000,
        clock_jump_s: float = 1.0,
    ):
        # The config file is validated where it is read; a config built in code is checked
        # here too, since every wait below derives from these durations.
        check_duration("heartbeat_timeout_s", config.heartbeat_timeout_s)
        check_duration("sync_period_s", config.sync_period_s, allow_zero=True)
        check_duration("max_tpdo_delay_s", config.tpdo_deadline_s)
        self.clock_jump_s = check_duration("clock_jump_s", clock_jump_s)
        self.config = config
        self.listen_only = listen_only
        self.log_path = None if log_path is None else Path(log_path)
        self.max_queue = max_queue
        self.decoder = TpdoDecoder(config)
        self._bus_in = bus
        self._producing = config.sync_period_s > 0 and not listen_only
        self._deadline = config.tpdo_deadline_s
        # A set no later frame closes (the bus went quiet) is closed after this, s: long enough
        # for a receive thread stalled by a busy computer to catch up on frames that were in time
        # (stalls of 0.15 s were seen on a loaded 2-core machine), and as long as a node may
        # stay quiet before it is reported silent; sooner with the bus down (no answer can come).
        self._close_after_down = 2 * config.sync_period_s + 0.1
        self._close_after = max(
            self._close_after_down if self._producing else 0.0, config.heartbeat_timeout_s
        )
        # A new clock offset is believed once frames have shown it for this long (s).
        self._jump_confirm_s = 2 * max(config.sync_period_s, self._deadline)
        self._leg_of_emcy = {c.emcy_cob_id: c.leg - 1 for c in config.legs}
        #: What the configuration step read from and set on each node (empty until start, and
        #: when ``config.configure`` is false or in listen-only mode).
        self.nodes: list[NodeInfo] = []
        # Legs (0..5) being set up over SDO: their PRE-OPERATIONAL heartbeat is expected then.
        self._configuring: set[int] = set()
        # 0: SYNC without a counter byte; 2..240: with a counter running 1..this (0x1019).
        self._sync_overflow = (
            SYNC_COUNTER_MAX if config.sync_counter is None else config.sync_counter
        )
        self._names = [c.name for c in config.legs]
        self._bus_name = config.bus_name

        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._stop_evt = threading.Event()
        self._worker: threading.Thread | None = None
        self._network: Network | None = None
        self._recorder: Recorder | None = None
        self._listener = Listener(self)
        # Whether the bus marks the echoes of our own frames (is_rx False): set at start.
        self._echo_marked = True
        # EDS files read from the devices (0x1021), by (vendor, product, revision).
        self._eds_cache: dict[tuple[int, ...], bytes] = {}
        self._reset_state()

    def _reset_state(self) -> None:
        # What outlives a stop/start: the sets not yet read and their numbering.
        self._queue: deque[ReadingSet] = deque()
        self._latest: ReadingSet | None = None
        self._index = 0
        self._incomplete = 0
        self._discarded = 0
        self._pending_faults: dict[str, str] = {}
        self._running = False
        self._stopped = False
        self._reset_run()

    def _reset_run(self) -> None:
        """Per-run state: what the bus and the nodes are doing now."""
        self._open: deque[_Pending] = deque()  # sets still taking positions, oldest first
        self._evidence = -math.inf  # latest bus time of a frame handled, s
        self._position_arrived = -math.inf  # host time the last position frame was handled, s
        self._last_closed_t_bus = -math.inf
        self._late_discarded = 0
        self._skipped_syncs = 0
        # The bus interface's clock against the host's (offset, jumps): learnt afresh each run.
        self._clock = BusClock(self._bus_name, self.clock_jump_s, self._jump_confirm_s)
        self._sync_counter = 0
        self._emergencies: list[Emergency | None] = [None] * 6  # the active error per node
        self._emcy_count = 0
        self._sync_sent = 0
        self._foreign_syncs = 0
        # The SYNCs sent lately (their sets, open or closed): echoes are matched against them.
        self._own_syncs: deque[_Pending] = deque(maxlen=64)
        self._t_start = time.monotonic()
        self._last_hb: list[float | None] = [None] * 6
        #: How many times each leg's node rebooted (a boot-up while running) since the start:
        #: every reading set carries these counts, so a pose recorded after a reboot is known.
        self._reboots = [0] * 6
        self._hb_state: list[int | None] = [None] * 6
        self._silent = [False] * 6
        self._last_nmt = [-math.inf] * 6
        self._frames = [0] * 6
        self._missing = [0] * 6
        self._bus_state = BUS_ACTIVE
        self._bus_detail = ""
        self._error_frames = 0
        self._polls_state = False
        self._next_state_poll = 0.0

    # -- lifecycle -------------------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        return self._running

    def open(self) -> LegEncoders:
        """:meth:`start` with its default timeout (the :class:`Device` interface)."""
        return self.start()

    def close(self) -> None:
        """:meth:`stop` (the :class:`Device` interface)."""
        self.stop()

    def start(self, timeout: float | None = None) -> LegEncoders:
        """Open the bus, NMT-start the six nodes and wait until each reports OPERATIONAL in its
        heartbeat (at most ``timeout`` s, default 2 × heartbeat_timeout_s), then produce SYNC
        (when ``sync_period_s`` > 0) and supervise heartbeats. In ``listen_only`` mode nothing is
        sent and nothing is awaited.

        Raises :class:`BusError` if the bus cannot be opened, :class:`EncoderSilent` naming the
        nodes that never sent a heartbeat, :class:`EncoderError` for a node that did not start.
        """
        if timeout is not None:
            timeout = check_duration("timeout", timeout)
        if self._running:
            return self
        self._reset_run()
        self._stopped = False
        self._stop_evt.clear()
        cfg = self.config
        self._recorder = Recorder(self.log_path) if self.log_path else None
        net = Network(self._bus_in, self._recorder)
        for k, leg in enumerate(cfg.legs):
            # canopen RemoteNode with the node's object dictionary: NMT master side, heartbeat
            # consumer, SDO client for the configuration step.
            node = net.add_node(leg.node_id, str(eds_for(cfg, leg)))
            node.nmt.add_heartbeat_callback(functools.partial(self._on_heartbeat, k))
        # canopen types the list by its own listener class; python-can's Notifier takes any
        # can.Listener.
        net.listeners.append(self._listener)  # type: ignore[arg-type]
        try:
            self._echo_marked = self._bus_in is None
            if self._bus_in is None:
                # Our own SYNCs echoed back, stamped when they were on the wire (SocketCAN's
                # loopback, the virtual bus): each set's exact SYNC time (_confirm_sync).
                try:
                    net.connect(**cfg.bus_kwargs(), receive_own_messages=self._producing)
                except can.CanInterfaceNotImplementedError:  # udp_multicast: unmarked echoes
                    self._echo_marked = False
                    net.connect(**cfg.bus_kwargs())
                    log.info("%s cannot mark echoes of sent frames", self._bus_name)
            else:
                net.connect()
        except Exception as exc:  # python-can raises many types for a missing adapter
            if self._recorder:
                self._recorder.stop()
            raise BusError(
                f"could not open {self._bus_name} at {cfg.bitrate // 1000} kbit/s: {exc} — check the "
                "interface name and channel in the configuration and that the adapter is plugged in "
                "and up (socketcan: `ip link set can0 up type can bitrate 1000000`)",
                BUS_ERROR,
            ) from exc
        self._network = net
        bus = net.bus
        assert bus is not None  # connect() opened it or was given it
        self._polls_state = type(bus).state is not can.BusABC.state
        self._t_start = time.monotonic()
        self._running = True
        try:
            if not self.listen_only:
                if cfg.configure:
                    self._configure(net)
                for k in range(6):
                    self._nmt_start(k)
                self._wait_operational(2 * cfg.heartbeat_timeout_s if timeout is None else timeout)
        except EncoderConfigError as exc:
            self.stop()
            raise EncoderError(str(exc)) from exc
        except BaseException:
            self.stop()
            raise
        self._worker = threading.Thread(target=self._run, name="hexcal-can-encoders", daemon=True)
        self._worker.start()
        return self

    def _configure(self, net: Network) -> None:
        """PRE-OPERATIONAL, then each node set up over SDO (:func:`configure_node`); the SYNC
        counter as the nodes expect. Raises :class:`EncoderConfigError`."""
        cfg = self.config
        self._configuring = set(range(6))
        try:
            for leg in cfg.legs:
                net[leg.node_id].nmt.send_command(NMT_CMD_PRE_OPERATIONAL)
            nodes, silent = [], []
            for leg in cfg.legs:
                try:
                    nodes.append(configure_node(net, leg, cfg, self._eds_cache))
                except EncoderConfigError as exc:
                    if not exc.silent:
                        raise
                    silent.append(exc)  # go on: name every node that does not answer
        finally:
            self._configuring = set()
        if silent:
            raise EncoderSilent(
                "; ".join(str(e) for e in silent),
                tuple(e.leg for e in silent),
                tuple(e.node_id for e in silent),
            )
        overflows = {n.sync_overflow for n in nodes}
        if len(overflows) > 1:
            listed = ", ".join(f"node 0x{n.node_id:02X}: {n.sync_overflow}" for n in nodes)
            raise EncoderConfigError(
                f"the encoders on {self._bus_name} expect different SYNC counters (0x1019: "
                f"{listed}) and one SYNC cannot suit them all — set sync_counter in the rig "
                "file's [can] table (0 = no counter) and hexcal writes it to every node"
            )
        self.nodes = nodes
        self._sync_overflow = overflows.pop()
        self.decoder.set_nodes(nodes)
        for n in nodes:
            log.info("%s: %s", self._names[n.leg - 1], n.identity)

    def stop(self) -> None:
        """Stop SYNC and supervision, wait briefly for the last SYNC's positions, close the set
        in progress (flagged if incomplete), stop receiving, close the log and the bus (if this
        driver opened it). Sets not yet read stay readable with :meth:`read_set`."""
        if self._network is None:
            return
        self._stop_evt.set()
        if self._worker is not None:
            self._worker.join(timeout=2.0)
            self._worker = None
        with self._cond:
            end = time.monotonic() + self._deadline
            while self._open and self._open[-1].n < 6 and time.monotonic() < end:
                self._cond.wait(end - time.monotonic())
        net = self._network
        if net.notifier is not None:
            net.notifier.stop(net.NOTIFIER_SHUTDOWN_TIMEOUT)
        with self._cond:
            while self._open:
                if self._open[0].n < 6:
                    self._open[0].faults["stopped"] = (
                        "acquisition stopped before all six positions of this SYNC arrived"
                    )
                self._close(time.monotonic())
            self._running = False
            self._stopped = True
            self._cond.notify_all()
        if self._recorder is not None:
            self._recorder.stop()
        if self._bus_in is None and net.bus is not None:
            net.bus.shutdown()
        self._network = None

    # -- reading ---------------------------------------------------------------------------------
    def read_set(self, timeout: float = 1.0) -> ReadingSet:
        """The next reading set in SYNC order (complete or flagged), waiting up to ``timeout`` s.

        Raises :class:`BusError` when none came and the bus is at fault, :class:`EncoderError`
        when none came otherwise (no SYNC on the bus, or the driver is stopped and drained).
        ``timeout`` is finite, >= 0 and at most :data:`~hexcal.drivers.limits.MAX_TIMEOUT_S`
        (ValueError otherwise)."""
        timeout = check_duration("timeout", timeout, allow_zero=True)
        end = time.monotonic() + timeout
        with self._cond:
            while not self._queue:
                if self._stopped or not self._running:
                    raise EncoderError(
                        f"the leg encoder driver on {self._bus_name} is stopped and every reading "
                        "set has been read — start it again"
                    )
                remaining = end - time.monotonic()
                if remaining <= 0:
                    if self._bus_state != BUS_ACTIVE:
                        raise BusError(self._bus_message(), self._bus_state)
                    raise EncoderError(
                        f"no reading set from {self._bus_name} in {timeout:g} s: no SYNC seen — "
                        + (
                            "the SYNC producer stopped; restart acquisition"
                            if self._producing
                            else "is the master producing SYNC? (sync_period_s = 0 means another "
                            "master must)"
                        )
                    )
                self._cond.wait(remaining)
            return self._queue.popleft()

    def latest(self) -> ReadingSet | None:
        """The most recently closed reading set (read or not), None before the first."""
        with self._lock:
            return self._latest

    def sample(self) -> LegSample:
        """The acquisition's ``LegSource``: the next set as a LegSample (stamped at its SYNC)."""
        timeout = max(1.0, 3 * self.config.sync_period_s, self.config.heartbeat_timeout_s)
        return self.read_set(timeout=timeout).to_leg_sample()

    def status(self) -> dict[str, Any]:
        """The bus and the six nodes now.

        Keys: ``bus`` (name), ``interface``, ``channel``, ``running``, ``listen_only``,
        ``bus_state`` ('ACTIVE', 'ERROR-PASSIVE', 'BUS-OFF', 'ERROR'), ``bus_detail``,
        ``error_frames``, ``sync_sent``, ``foreign_syncs``, ``sets``, ``incomplete_sets``,
        ``late_discarded`` (positions that came after their set had closed),
        ``skipped_syncs`` (SYNCs the producer skipped after a stall of its thread),
        ``clock_jumps`` (times the bus clock jumped and attribution re-anchored),
        ``untrusted_stamps`` (frames whose bus time was not trusted), ``emergencies`` (EMCY
        frames received), ``sync_counter`` (0x1019: 0 = SYNC without counter), ``queued``,
        ``discarded``, and ``legs``: six dicts with ``leg``, ``node_id``, ``alive``,
        ``heartbeat_age_s`` (s, None if never heard), ``nmt_state`` (name, None if never heard),
        ``tpdo_frames``, ``missing`` (sets without this leg's position), ``emergency`` (the
        node's active EMCY in words, None) and ``node`` (what the configuration step read, see
        :class:`~hexcal.drivers.can_nodes.NodeInfo`; None when not configured).
        """
        now = time.monotonic()
        with self._lock:
            legs = []
            for k, c in enumerate(self.config.legs):
                hb = self._last_hb[k]
                st = self._hb_state[k]
                legs.append(
                    {
                        "leg": c.leg,
                        "node_id": c.node_id,
                        "alive": hb is not None and now - hb <= self.config.heartbeat_timeout_s,
                        "heartbeat_age_s": None if hb is None else now - hb,
                        "nmt_state": None if st is None else NMT_STATES.get(st, f"0x{st:02X}"),
                        "tpdo_frames": self._frames[k],
                        "missing": self._missing[k],
                        "emergency": None
                        if self._emergencies[k] is None
                        else self._emergencies[k].describe(self._names[k]),  # type: ignore[union-attr]
                        "node": None if not self.nodes else self.nodes[k].to_dict(),
                    }
                )
            return {
                "bus": self._bus_name,
                "interface": self.config.interface,
                "channel": self.config.channel,
                "running": self._running,
                "listen_only": self.listen_only,
                "bus_state": self._bus_state,
                "bus_detail": self._bus_detail,
                "error_frames": self._error_frames,
                "sync_sent": self._sync_sent,
                "foreign_syncs": self._foreign_syncs,
                "sets": self._index,
                "incomplete_sets": self._incomplete,
                "late_discarded": self._late_discarded,
                "skipped_syncs": self._skipped_syncs,
                "clock_jumps": self._clock.jumps,
                "untrusted_stamps": self._clock.untrusted,
                "emergencies": self._emcy_count,
                "sync_counter": self._sync_overflow,
                "queued": len(self._queue),
                "discarded": self._discarded,
                "legs": legs,
            }

    def check(self) -> None:
        """Raise :class:`BusError` if the bus is not error-active, :class:`EncoderSilent` if a
        node's heartbeat is overdue; return quietly when all is well."""
        now = time.monotonic()
        with self._lock:
            if self._bus_state != BUS_ACTIVE:
                raise BusError(self._bus_message(), self._bus_state)
            silent = [k for k in range(6) if self._age(k, now) > self.config.heartbeat_timeout_s]
            if silent:
                raise EncoderSilent(
                    "; ".join(self._silent_message(k, now) for k in silent),
                    tuple(k + 1 for k in silent),
                    tuple(self.config.legs[k].node_id for k in silent),
                )

    # -- messages ---------------------------------------------------------------------------------
    def _age(self, k: int, now: float) -> float:
        hb = self._last_hb[k]
        return now - (self._t_start if hb is None else hb)

    def _silent_message(self, k: int, now: float) -> str:
        return (
            f"{self._names[k]} silent for {self._age(k, now):.1f} s on {self._bus_name}: no heartbeat "
            f"(timeout {self.config.heartbeat_timeout_s:g} s) — check that encoder's power and cable; "
            "its readings are not trusted until it is back"
        )

    def _bus_message(self) -> str:
        cfg = self.config
        kbit = f"{cfg.bitrate / 1000:g} kbit/s"
        detail = f" ({self._bus_detail})" if self._bus_detail else ""
        if self._bus_state == BUS_OFF:
            return (
                f"{self._bus_name} is BUS-OFF{detail}: the CAN controller stopped after too many "
                "errors and nothing is sent or received — check the cable, the 120 Ω termination at "
                f"both ends and that every node runs at {kbit}, then restart acquisition"
            )
        if self._bus_state == BUS_PASSIVE:
            return (
                f"{self._bus_name} is ERROR-PASSIVE{detail}: many transmission errors — check the "
                f"cable, the 120 Ω termination at both ends and that every node runs at {kbit}"
            )
        return (
            f"{self._bus_name} is in error{detail} — check that the adapter is plugged in and the "
            "interface is up, then restart acquisition"
        )

    def _note(self, key: str, message: str) -> None:
        """Attach a fault to the newest open set, or to the next set if none is open. Lock held."""
        target = self._open[-1].faults if self._open else self._pending_faults
        target[key] = message

    # -- sending ---------------------------------------------------------------------------------
    def _nmt_start(self, k: int) -> None:
        net = self._network
        if net is None:
            return
        node_id = self.config.legs[k].node_id
        self._last_nmt[k] = time.monotonic()
        try:
            # canopen's NMT master: 0x000 [0x01, node]. Per node, never broadcast: other nodes
            # on a shared bus are not ours to start.
            net[node_id].nmt.send_command(NMT_CMD_START)
        except (can.CanError, OSError) as exc:
            with self._lock:
                self._bus_state, self._bus_detail = BUS_ERROR, f"NMT start failed: {exc}"
                self._note("send", self._bus_message())

    def _send_sync(self) -> None:
        rec = self._recorder
        with rec.lock if rec else contextlib.nullcontext():
            self._send_sync_locked()

    def _send_sync_locked(self) -> None:
        net = self._network
        assert net is not None
        overflow = self._sync_overflow
        self._sync_counter = self._sync_counter % overflow + 1 if overflow else 0
        with self._lock:
            # Open the set before sending: the answers may arrive before send() returns. The
            # SYNC goes on the wire between now and then (a busy host can stall this thread in
            # between): its set is not closed, nor its answers judged late, before that is known.
            t = time.monotonic()
            s = self._open_set(t, self._clock.to_bus(t), self._sync_counter, math.inf)
            self._own_syncs.append(s)
        try:
            # No counter byte for nodes whose 0x1019 is 0: they answer one with EMCY 0x8240.
            net.sync.transmit(self._sync_counter or None)
        except (can.CanError, OSError) as exc:
            with self._lock:
                self._bus_state, self._bus_detail = BUS_ERROR, f"sending SYNC failed: {exc}"
                self._note("send", self._bus_message())
                self._close_all()
            return
        t_sent = time.monotonic()
        with self._lock:
            if not s.echoed:  # the echo gives the exact wire time; without one, a bound
                s.t_bus_hi = self._clock.to_bus(t_sent)
        self._sync_sent += 1
        if self._bus_state == BUS_ERROR and self._bus_detail.startswith("sending SYNC"):
            with self._lock:
                self._bus_state, self._bus_detail = BUS_ACTIVE, ""

    # -- SYNC producer and supervision thread ------------------------------------------------------
    def _run(self) -> None:
        period = self.config.sync_period_s if self._producing else 0.0
        tick = min(period, 0.01) if period else 0.01
        next_sync = next_tick = time.monotonic()
        while not self._stop_evt.is_set():
            now = time.monotonic()
            if period and now >= next_sync:
                self._send_sync()
                # A late SYNC must not be followed at once by a catch-up one: the answers to
                # the first need their deadline before the next SYNC goes on the bus — counted
                # from when the send returned, since a busy host can stall it (or this loop).
                on_time = next_sync + period
                next_sync = max(on_time, time.monotonic() + self._deadline)
                missed = int((next_sync - on_time) / period)
                if missed:  # a stall (busy machine): skipped, no burst of SYNCs
                    # Positions are placed by bus time, so a gap between SYNCs harms no set:
                    # counted and logged, not flagged.
                    with self._lock:
                        self._skipped_syncs += missed
                    log.info(
                        "the SYNC producer on %s stalled and skipped %d SYNCs (computer busy?)",
                        self._bus_name,
                        missed,
                    )
            if now >= next_tick:
                self._supervise(now)
                next_tick = now + tick
            wake = min(next_sync, next_tick) if period else next_tick
            self._stop_evt.wait(max(0.0, wake - time.monotonic()))

    def _supervise(self, now: float) -> None:
        with self._lock:
            # By time only while no position comes at all (the bus went quiet): while positions
            # come, the later ones close the sets (bus time, in order), however late they are
            # handled — a busy host delays frames that were on time, it does not lose them.
            # Counted from when the SYNC was sent (a host stall can hold it back after its set
            # opened: no answer is due before), never for one still being sent.
            after = self._close_after if self._bus_state == BUS_ACTIVE else self._close_after_down
            quiet = now - self._position_arrived > after
            while quiet and self._open and now - self._open[0].t_sent > after:
                self._close(now)
            for k in range(6):
                if not self._silent[k] and self._age(k, now) > self.config.heartbeat_timeout_s:
                    self._silent[k] = True
                    log.warning("%s", self._silent_message(k, now))
        if self._polls_state and now >= self._next_state_poll and self._network is not None:
            self._next_state_poll = now + 0.1
            try:
                bus = self._network.bus
                if bus is None:
                    return
                st = bus.state
            except Exception:  # an interface without state support: nothing to learn
                self._polls_state = False
                return
            with self._lock:
                if st == can.BusState.ERROR:
                    self._bus_state, self._bus_detail = BUS_OFF, "reported by the interface"
                elif st == can.BusState.PASSIVE:
                    self._bus_state, self._bus_detail = BUS_PASSIVE, "reported by the interface"
                elif self._bus_detail == "reported by the interface":
                    self._bus_state, self._bus_detail = BUS_ACTIVE, ""

    def _wait_operational(self, timeout: float) -> None:
        end = time.monotonic() + timeout
        with self._cond:
            while True:
                waiting = [k for k in range(6) if self._hb_state[k] != NMT_OPERATIONAL]
                if not waiting:
                    return
                remaining = end - time.monotonic()
                if remaining <= 0:
                    break
                self._cond.wait(remaining)
            now = time.monotonic()
            silent = [k for k in waiting if self._last_hb[k] is None]
            if silent:
                raise EncoderSilent(
                    "; ".join(
                        f"{self._names[k]} silent for {self._age(k, now):.1f} s after NMT start"
                        for k in silent
                    )
                    + f" on {self._bus_name}: no heartbeat — check that "
                    + ("it is" if len(silent) == 1 else "they are")
                    + " powered and wired to this bus, the node ids and that the heartbeat "
                    "producer (object 0x1017) is on, then start again",
                    tuple(k + 1 for k in silent),
                    tuple(self.config.legs[k].node_id for k in silent),
                )
            k = waiting[0]
            st = self._hb_state[k]
            raise EncoderError(
                f"{self._names[k]} stays in NMT state {NMT_STATES.get(st or 0, hex(st or 0))} after "
                f"NMT start on {self._bus_name} — check the node for an error (EMCY) and power-cycle it"
            )


__all__ = [
    "BusError",
    "EncoderError",
    "EncoderSilent",
    "LegEncoders",
    "ReadingSet",
    "TpdoDecoder",
    "decode_tpdo",
    "describe_error_frame",
]
