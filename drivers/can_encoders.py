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
SYNCs are stamped with ``time.monotonic()`` and put on the bus clock by the offset between the
two clocks (the smallest arrival − bus time seen over the last few seconds). Several sets may
be open at once; a set closes once a frame stamped more than ``tpdo_deadline_s`` after its SYNC
has been handled (frames on one bus arrive in order, so nothing in time for it can still come),
or, when the bus goes quiet, ``close_after`` after its SYNC. A position for a set already closed
is discarded (that set was flagged with the position missing); two positions from one node for
one SYNC flag the set. Produced SYNCs are kept at least ``tpdo_deadline_s`` apart, so after a
stall no catch-up SYNC can overtake the answers to the one before.

Clock jumps. The bus interface's clock is not the host's and can jump: an adapter that resets
restarts its clock, SocketCAN stamps with the system time, which an operator or NTP may step,
and one corrupt timestamp is enough to matter. A frame whose (arrival − bus time) differs from
the learnt offset by more than ``clock_jump_s`` (1 s by default: a thousand times the jitter of
a stamp, more than any stall a working receive thread has) cannot be placed on the bus clock,
so its bus time is not trusted: it takes no part in attribution, closing or the offset, and a
position it carries is discarded and its set flagged (naming the leg and the jump). When the
next frame is on the known clock again, those were stray stamps: the driver says so (a warning
naming the bus and the offset the first time, at info level after). If instead frames keep
coming with one new offset (at least three, over more than two SYNC periods) the clock itself
has jumped: the driver re-anchors — the new offset replaces the old one and the open sets are
moved onto the new clock — logs a warning naming the bus and the jump, once, and flags the set
it happens in. A single frame stamped an hour off thus costs one flagged set, a clock reset a
few; neither leaves the driver stuck until a restart. (``status()`` counts both.)

Anything unusual during a set — a position missing, late or twice, a silent node, a node not
OPERATIONAL, a CAN error frame, the bus not error-active, a SYNC that could not be sent — is
written into that set's ``faults`` and the set is not ``complete``. No set is dropped: every
SYNC gives exactly one set, in order, numbered by ``index``. The raw traffic can be written to
a python-can log (``log_path``: .asc, .blf, .csv, .log, ...) and replayed later through
:class:`LegEncoders` in ``listen_only`` mode.

Known limit: a node that answers every SYNC more than a whole period late (a broken node) looks
on the bus like one that answers on time, one SYNC behind; only its first, missing position is
flagged. Real CiA 406 encoders latch in hardware at the SYNC and answer within microseconds.
"""

from __future__ import annotations

import contextlib
import copy
import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

import can
import canopen
import numpy as np
from canopen.nmt import NMT_STATES

from hexcal.acquisition import LegSample
from hexcal.drivers.can_config import (
    SYNC_COB_ID,
    CanBusConfig,
    LegEncoderConfig,
)
from hexcal.drivers.can_emcy import Emergency
from hexcal.drivers.can_nodes import EncoderConfigError, NodeInfo, configure_node, eds_for
from hexcal.drivers.limits import check_duration

log = logging.getLogger(__name__)

NMT_OPERATIONAL = 0x05
NMT_PRE_OPERATIONAL = 0x7F
NMT_BOOTUP = 0x00
NMT_CMD_START = 0x01
NMT_CMD_PRE_OPERATIONAL = 0x80

#: CiA 301: a SYNC counter runs 1..overflow; 240 is the largest overflow value allowed.
SYNC_COUNTER_MAX = 240

# SocketCAN error classes (linux/can/error.h): the error frame's arbitration id is a bit mask.
# Other interfaces deliver error frames with id 0; they still count as error frames.
CAN_ERR_TX_TIMEOUT = 0x001
CAN_ERR_LOSTARB = 0x002
CAN_ERR_CRTL = 0x004
CAN_ERR_PROT = 0x008
CAN_ERR_TRX = 0x010
CAN_ERR_ACK = 0x020
CAN_ERR_BUSOFF = 0x040
CAN_ERR_BUSERROR = 0x080
CAN_ERR_RESTARTED = 0x100
# data[1] of a CAN_ERR_CRTL frame
CAN_ERR_CRTL_RX_PASSIVE = 0x10
CAN_ERR_CRTL_TX_PASSIVE = 0x20
CAN_ERR_CRTL_ACTIVE = 0x40

_ERROR_CLASSES = (
    (CAN_ERR_TX_TIMEOUT, "transmit timeout"),
    (CAN_ERR_LOSTARB, "lost arbitration"),
    (CAN_ERR_CRTL, "controller problem"),
    (CAN_ERR_PROT, "protocol violation"),
    (CAN_ERR_TRX, "transceiver problem"),
    (CAN_ERR_ACK, "no acknowledge (is any other node powered?)"),
    (CAN_ERR_BUSOFF, "bus-off"),
    (CAN_ERR_BUSERROR, "bus error"),
    (CAN_ERR_RESTARTED, "controller restarted"),
)

BUS_ACTIVE = "ACTIVE"
BUS_PASSIVE = "ERROR-PASSIVE"
BUS_OFF = "BUS-OFF"
BUS_ERROR = "ERROR"


# -- errors ----------------------------------------------------------------------------------------
class EncoderError(Exception):
    """The leg encoders cannot deliver readings; the message says what to check."""


class EncoderSilent(EncoderError):
    """One or more encoder nodes sent no heartbeat within the timeout.

    ``legs`` (1..6) and ``node_ids`` name them, in the same order."""

    def __init__(self, message: str, legs: tuple[int, ...] = (), node_ids: tuple[int, ...] = ()):
        super().__init__(message)
        self.legs = legs
        self.node_ids = node_ids


class BusError(EncoderError):
    """The CAN bus itself is at fault (cannot open, bus-off, error-passive, send failed).

    ``state`` is the bus state as :meth:`LegEncoders.status` reports it."""

    def __init__(self, message: str, state: str = BUS_ERROR):
        super().__init__(message)
        self.state = state


# -- decoding --------------------------------------------------------------------------------------
class TpdoDecoder:
    """The position TPDO → (leg, mm) for one configuration, precompiled so decoding a frame is
    one dict lookup and one integer conversion.

    ``table`` maps the TPDO's COB-ID (TPDO ``config.tpdo`` of each node) to (leg 1..6, sign,
    counts_per_mm, zero_mm). ``signed`` (6,) says how each node's 0x6004 is decoded (INTEGER32
    by default; :meth:`set_nodes` takes it from the nodes' object dictionaries) and ``ranges``
    (6,) its total measuring range in counts (None: no wrap-around). With a range, a position
    is unwrapped against the leg's previous one (:meth:`counts`): the first position is taken
    as the node reports it, and moves across the wrap point continue from there.
    """

    __slots__ = (
        "_cpm",
        "_last",
        "_leg_of",
        "_sign",
        "_zero",
        "config",
        "ranges",
        "signed",
        "table",
    )

    def __init__(self, config: CanBusConfig):
        self.config = config
        self.signed = [True] * 6
        self.ranges: list[int | None] = [None] * 6
        self._last: list[tuple[int, int] | None] = [None] * 6  # (raw, unwrapped) counts
        self.table: dict[int, tuple[int, int, float, float]] = {
            c.tpdo_cob_id(config.tpdo): (c.leg, c.sign, c.counts_per_mm, c.zero_mm)
            for c in config.legs
        }
        # Lookup arrays over the whole 11-bit id space for the batch path (leg 0 = not a TPDO1).
        self._leg_of = np.zeros(0x800, np.int64)
        self._sign = np.zeros(0x800)
        self._cpm = np.ones(0x800)
        self._zero = np.zeros(0x800)
        for c in config.legs:
            i = c.tpdo_cob_id(config.tpdo)
            self._leg_of[i], self._sign[i], self._cpm[i], self._zero[i] = (
                c.leg,
                c.sign,
                c.counts_per_mm,
                c.zero_mm,
            )

    def set_nodes(self, nodes: list[NodeInfo]) -> None:
        """Decode as the nodes' object dictionaries say (data type of 0x6004, range 0x6002)."""
        for info in nodes:
            self.signed[info.leg - 1] = info.position_type == "INTEGER32"
            self.ranges[info.leg - 1] = info.total_range or None
        self._last = [None] * 6

    def counts(self, k: int, data: bytes | bytearray) -> int:
        """Leg ``k`` (0..5)'s position in counts from the TPDO's first four bytes, unwrapped at
        the total measuring range when the node has one."""
        raw = int.from_bytes(data[:4], "little", signed=self.signed[k])
        span = self.ranges[k]
        if span is None:
            return raw
        last = self._last[k]
        value = raw
        if last is not None:
            step = (raw - last[0] + span // 2) % span - span // 2
            value = last[1] + step
        self._last[k] = (raw, value)
        return value

    def decode(self, msg: can.Message) -> tuple[int, float] | None:
        """(leg 1..6, reading mm, finite) of the position TPDO of a configured node; None for
        any other frame.

        Raises :class:`EncoderError` for a TPDO too short to hold 0x6004, and for counts the
        leg's scaling cannot turn into a finite reading."""
        entry = self.table.get(msg.arbitration_id)
        if entry is None or msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame:
            return None
        data = msg.data
        if len(data) < 4:
            raise EncoderError(
                _short_tpdo_message(self.config.leg(entry[0]), len(data), self.config)
            )
        leg, sign, cpm, zero = entry
        counts = self.counts(leg - 1, data)
        mm = sign * counts / cpm + zero
        if not math.isfinite(mm):
            raise EncoderError(_nonfinite_message(self.config.leg(leg), counts, self.config))
        return leg, mm

    def decode_batch(
        self, cob_ids: np.ndarray, payload: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Vectorised decode of N standard data frames (INTEGER32 or UNSIGNED32 per leg as
        ``signed`` says; no unwrapping, which needs the frames one by one).

        ``cob_ids`` (N,) int; ``payload`` (N, ≥4) uint8 (the frames' data bytes). Returns legs
        (N,) int (0 where the frame is not a configured position TPDO) and readings (N,) mm
        (NaN there, and where the leg's scaling gives no finite reading: :meth:`decode` raises
        there).
        """
        ids = np.asarray(cob_ids, np.int64)
        legs = np.zeros(ids.shape, np.int64)
        inside = (ids >= 0) & (ids < 0x800)
        legs[inside] = self._leg_of[ids[inside]]
        raw = np.ascontiguousarray(np.asarray(payload, np.uint8)[:, :4])
        counts = raw.view("<i4")[:, 0].astype(float)
        unsigned = np.array([not s for s in self.signed] + [False])[np.maximum(legs, 1) - 1]
        counts = np.where(unsigned & (counts < 0), counts + 2.0**32, counts)
        idx = np.where(legs > 0, ids, 0)
        with np.errstate(over="ignore", invalid="ignore"):  # flagged just below, not warned
            mm = self._sign[idx] * counts / self._cpm[idx] + self._zero[idx]
        mm[(legs == 0) | ~np.isfinite(mm)] = np.nan
        return legs, mm


def decode_tpdo(msg: can.Message, config: CanBusConfig | TpdoDecoder) -> tuple[int, float] | None:
    """(leg 1..6, reading mm) of one position TPDO, or None when the frame is not the position
    TPDO of a configured node. ``reading_mm = sign × counts / counts_per_mm + zero_mm``.

    Pass a :class:`TpdoDecoder` (built once from the config) on a hot path; a
    :class:`CanBusConfig` works too but compiles the lookup on every call.
    """
    dec = config if isinstance(config, TpdoDecoder) else TpdoDecoder(config)
    return dec.decode(msg)


def describe_error_frame(msg: can.Message) -> str:
    """What an error frame says, in words (SocketCAN error classes; 'error frame' otherwise)."""
    cls = msg.arbitration_id & 0x1FFFFFFF
    words = [text for bit, text in _ERROR_CLASSES if cls & bit]
    if cls & CAN_ERR_CRTL and len(msg.data) > 1:
        ctrl = msg.data[1]
        if ctrl & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE):
            words.append("controller error-passive")
        if ctrl & CAN_ERR_CRTL_ACTIVE:
            words.append("controller back to error-active")
    return ", ".join(words) or "error frame"


def _nonfinite_message(leg: LegEncoderConfig, counts: int, config: CanBusConfig) -> str:
    return (
        f"{leg.name} sent {counts} counts on {config.bus_name}, which its scaling "
        f"(counts_per_mm {leg.counts_per_mm:g}, zero_mm {leg.zero_mm:g}) turns into no finite "
        "reading — position discarded; check that leg's scaling in the CAN configuration"
    )


def _short_tpdo_message(leg: LegEncoderConfig, n: int, config: CanBusConfig) -> str:
    return (
        f"{leg.name} sent a {n}-byte TPDO{config.tpdo} on {config.bus_name}; expected at least 4 "
        f"bytes (0x6004 mapped first) — check that node's TPDO{config.tpdo} mapping (hexcal sets "
        "it when can.configure is true)"
    )


# -- reading sets ----------------------------------------------------------------------------------
@dataclass
class ReadingSet:
    """The six legs' positions answering one SYNC.

    ``sync_counter``: the counter byte the SYNC carried (1..240), 0 if it carried none.
    ``t_sync``: monotonic time (s) the SYNC was sent (driver-produced) or was on the bus.
    ``readings_mm``: (6,) mm, leg k at index k − 1, NaN where no position arrived.
    ``arrival``: (6,) monotonic s each position was on the bus (``t_sync`` + its bus-time delay
    after the SYNC), NaN where none came.
    ``complete``: all six arrived in time and nothing went wrong; otherwise ``faults`` says what
    (operator sentences naming leg, node, bus and what to do).
    ``index``: 0, 1, 2... in SYNC order since :meth:`LegEncoders.start`; never skips.
    """

    sync_counter: int
    t_sync: float
    readings_mm: np.ndarray
    arrival: np.ndarray
    complete: bool
    faults: list[str] = field(default_factory=list)
    index: int = 0

    def to_leg_sample(self) -> LegSample:
        """This set as the acquisition's :class:`~hexcal.acquisition.LegSample`, stamped with the
        SYNC time (the instant the six encoders latched their positions)."""
        faults = tuple(self.faults)
        if not self.complete and not faults:  # cannot happen by construction; never hide it
            faults = ("leg encoder reading set incomplete",)
        return LegSample(self.t_sync, self.readings_mm.copy(), faults)


class _JumpCandidate:
    """Frames stamped off the bus clock by about one amount, since ``first_t`` (monotonic s):
    a clock jump once enough of them agree (see :meth:`LegEncoders._clock_step`)."""

    __slots__ = ("first_t", "frames", "lag", "lag_min", "offset")

    def __init__(self, first_t: float, lag: float, offset: float):
        self.first_t = first_t
        self.lag = lag  # the first frame's arrival − bus time, s
        self.lag_min = lag  # the smallest of them, s: the new offset if it is a jump
        self.offset = offset  # the offset (s) they stray from
        self.frames = 0


class _Pending:
    """A set being assembled (plain lists: faster per frame than numpy element writes)."""

    __slots__ = ("arrival", "counter", "faults", "index", "n", "readings", "t_bus", "t_sync")

    def __init__(
        self, index: int, counter: int, t_sync: float, t_bus: float, faults: dict[str, str]
    ):
        self.index = index
        self.counter = counter
        self.t_sync = t_sync  # monotonic s
        self.t_bus = t_bus  # the same instant on the bus interface's clock, s
        self.readings = [math.nan] * 6
        self.arrival = [math.nan] * 6
        self.n = 0
        self.faults = faults  # key -> message; a key repeats (error frames) without piling up


# -- python-can glue -------------------------------------------------------------------------------
class _Listener(can.Listener):
    def __init__(self, owner: LegEncoders):
        self.owner = owner

    def on_message_received(self, msg: can.Message) -> None:
        self.owner._on_message(msg)

    def on_error(self, exc: Exception) -> None:
        self.owner._on_receive_error(exc)

    def stop(self) -> None:
        pass


class _Recorder:
    """A python-can log writer shared by the receive thread and the senders.

    ``lock`` (reentrant) is held by the receive thread across writing *and* handling a frame,
    and by the SYNC producer across opening a set, sending and writing the SYNC: so the log's
    order is the order the driver saw, and a replay assigns every position to the same SYNC."""

    def __init__(self, path: Path):
        self.path = path
        self.writer = can.Logger(str(path))
        self.lock = threading.RLock()
        self.closed = False

    def write(self, msg: can.Message) -> None:
        """Write one frame; the caller holds ``lock``."""
        if self.closed:
            return
        if not isinstance(msg.channel, (int, type(None))):
            # Virtual channel names are not channel numbers; BLF stores a 16-bit number.
            msg = copy.copy(msg)
            msg.channel = None
        self.writer.on_message_received(msg)

    def stop(self) -> None:
        with self.lock:
            if not self.closed:
                self.closed = True
                self.writer.stop()


class _Network(canopen.Network):
    """canopen's Network with a shorter notifier cycle (stop() returns in ~50 ms, not 1 s) and
    every frame it sends written to the recorder, under the recorder's lock so the log keeps
    the true order (our SYNC before the answers to it)."""

    NOTIFIER_CYCLE = 0.05
    NOTIFIER_SHUTDOWN_TIMEOUT = 1.0

    def __init__(self, bus: can.BusABC | None, recorder: _Recorder | None):
        super().__init__(bus)
        self.recorder = recorder

    def send_message(self, can_id: int, data: Any, remote: bool = False) -> None:
        if not self.bus:
            raise RuntimeError("Not connected to CAN bus")
        msg = can.Message(
            arbitration_id=can_id,
            data=bytes(data or b""),
            is_extended_id=can_id > 0x7FF,
            is_remote_frame=remote,
            is_rx=False,
            timestamp=time.time(),
        )
        rec = self.recorder
        with rec.lock if rec else contextlib.nullcontext(), self.send_lock:
            self.bus.send(msg)
            if rec:
                rec.write(msg)
        self.check()


# -- the driver ------------------------------------------------------------------------------------
class LegEncoders:
    """The six leg encoders on one CAN bus.

    ``config``: bus and legs. ``bus``: an open python-can bus to use (the caller keeps owning
    it); None opens ``config.interface``/``config.channel`` at :meth:`start` and closes it at
    :meth:`stop`. ``listen_only``: send nothing (no NMT, no SYNC) and decode what is on the bus —
    for sniffing a bus another master runs, or replaying a log. ``log_path``: write every frame
    received and sent to this python-can log (.asc, .blf, ...). ``max_queue``: reading sets kept
    for :meth:`read_set` (100 000 ≈ 17 min at 100 Hz); beyond it the oldest are discarded and the
    next set says so. ``clock_jump_s``: how far (s) a frame's bus time may stray from the learnt
    bus-to-host clock offset before it is taken for a clock jump (module docstring). The
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
        # for a receive thread stalled by a busy computer to catch up on frames that were in time.
        self._close_after = (
            2 * config.sync_period_s + 0.1 if self._producing else config.heartbeat_timeout_s
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
        self._network: _Network | None = None
        self._recorder: _Recorder | None = None
        self._listener = _Listener(self)
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
        self._last_closed_t_bus = -math.inf
        self._late_discarded = 0
        self._skipped_syncs = 0
        # Bus clock → monotonic: the smallest (arrival − bus time) in this and the last window.
        self._offset_min = [math.inf, math.inf]
        self._offset_window_end = 0.0
        self._jump: _JumpCandidate | None = None  # frames off the clock, not yet explained
        self._clock_jumps = 0
        self._untrusted_stamps = 0
        self._warned_stamp = False
        self._sync_counter = 0
        self._emergencies: list[Emergency | None] = [None] * 6  # the active error per node
        self._emcy_count = 0
        self._sync_sent = 0
        self._foreign_syncs = 0
        self._t_start = time.monotonic()
        self._last_hb: list[float | None] = [None] * 6
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
        self._recorder = _Recorder(self.log_path) if self.log_path else None
        net = _Network(self._bus_in, self._recorder)
        for k, leg in enumerate(cfg.legs):
            # canopen RemoteNode with the node's object dictionary: NMT master side, heartbeat
            # consumer, SDO client for the configuration step.
            node = net.add_node(leg.node_id, str(eds_for(cfg, leg)))
            node.nmt.add_heartbeat_callback(lambda state, k=k: self._on_heartbeat(k, state))
        net.listeners.append(self._listener)
        try:
            if self._bus_in is None:
                net.connect(**cfg.bus_kwargs())
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
        self._polls_state = type(net.bus).state is not can.BusABC.state
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

    def _configure(self, net: _Network) -> None:
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
                    nodes.append(configure_node(net, leg, cfg))
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

    def __enter__(self) -> LegEncoders:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

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
                "clock_jumps": self._clock_jumps,
                "untrusted_stamps": self._untrusted_stamps,
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

    # -- clocks ----------------------------------------------------------------------------------
    def _bus_time(self, msg: can.Message, t: float) -> tuple[float, bool]:
        """The frame's bus time (s on the interface's clock) and whether it is trusted; learns
        the clock offset and follows its jumps (module docstring). ``t`` is the frame's
        monotonic arrival time. Lock held."""
        stamp = msg.timestamp
        # No stamp (or no number): stamped on arrival, on the wall clock as python-can does.
        ts = stamp if stamp and math.isfinite(stamp) else time.time() - time.monotonic() + t
        if t >= self._offset_window_end:  # a fresh window every 5 s follows clock drift
            self._offset_min = [math.inf, self._offset_min[0]]
            self._offset_window_end = t + 5.0
        lag = t - ts
        offset = min(self._offset_min)
        if offset != math.inf and abs(lag - offset) > self.clock_jump_s:
            return ts, self._clock_step(t, lag, offset)
        if self._jump is not None:  # on the known clock again: what strayed were frames' stamps
            self._stray_stamps(self._jump)
            self._jump = None
        if lag < self._offset_min[0]:
            self._offset_min[0] = lag
        return ts, True

    def _clock_step(self, t: float, lag: float, offset: float) -> bool:
        """A frame arrived ``lag`` s after its bus time, ``offset`` expected: count it towards a
        clock jump; True when it confirms one (the driver re-anchored: its stamp holds now)."""
        jump = self._jump
        if jump is None or abs(lag - jump.lag) > self.clock_jump_s / 2:
            if jump is not None:
                self._stray_stamps(jump)
            jump = self._jump = _JumpCandidate(t, lag, offset)
        jump.lag_min = min(jump.lag_min, lag)
        jump.frames += 1
        if jump.frames >= 3 and t - jump.first_t >= self._jump_confirm_s:
            self._reanchor(jump.lag_min, offset)
            return True
        self._untrusted_stamps += 1
        return False

    def _stray_stamps(self, jump: _JumpCandidate) -> None:
        """Frames stamped off the clock turned out not to be a jump (the frames after them are
        on the known clock): say so — a warning the first time, then at info level."""
        level = logging.INFO if self._warned_stamp else logging.WARNING
        self._warned_stamp = True
        log.log(
            level,
            "%s: %d frame(s) stamped %+.3f s off the bus clock (against the host clock) — "
            "their bus times were not trusted, positions in them discarded and their sets "
            "flagged; the clock itself did not jump (a corrupt timestamp?)",
            self._bus_name,
            jump.frames,
            jump.offset - jump.lag,
        )

    def _reanchor(self, new: float, old: float) -> None:
        """The bus clock jumped: (arrival − bus time) is ``new`` s now, ``old`` s before. Move
        the open sets, the closing evidence and the offset onto the new clock."""
        shift = old - new  # a bus time on the old clock + shift = the same instant on the new
        for s in self._open:
            s.t_bus += shift
        self._evidence += shift
        self._last_closed_t_bus += shift
        self._offset_min = [new, new]
        self._jump = None
        self._clock_jumps += 1
        message = (
            f"the clock of {self._bus_name} jumped {shift:+.3f} s (frame timestamps against the "
            "host clock: the interface's clock was reset or the system time stepped) — SYNC "
            "attribution re-anchored to the new clock; sets around the jump are flagged"
        )
        log.warning("%s", message)
        self._note("clock_jump", message)

    def _to_bus(self, t: float) -> float:
        """Monotonic time ``t`` on the bus clock (the offset errs early: a frame is never
        placed before the SYNC it answers)."""
        offset = min(self._offset_min)
        if offset == math.inf:
            offset = time.monotonic() - time.time()
        return t - offset

    # -- assembling sets (lock held) --------------------------------------------------------------
    def _open_set(self, t: float, t_bus: float, counter: int) -> None:
        faults, self._pending_faults = self._pending_faults, {}
        for k, em in enumerate(self._emergencies):
            if em is not None:  # the node still reports an error: its readings are suspect
                faults[f"emcy{k}"] = em.describe(self._names[k])
        self._open.append(_Pending(self._index, counter, t, t_bus, faults))
        self._index += 1

    def _close_until(self, evidence: float) -> None:
        """Close the open sets whose answers are all due before bus time ``evidence``."""
        self._evidence = max(self._evidence, evidence)
        while self._open and self._open[0].t_bus + self._deadline < self._evidence:
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
            with rec.lock:
                rec.write(msg)
                self._dispatch(msg, t)
        else:
            self._dispatch(msg, t)

    def _dispatch(self, msg: can.Message, t: float) -> None:
        with self._lock:
            ts, trusted = self._bus_time(msg, t)
        if msg.is_error_frame:
            self._on_error_frame(msg, t)
            return
        if msg.is_remote_frame or msg.is_extended_id:
            return
        cid = msg.arbitration_id
        entry = self.decoder.table.get(cid)
        if entry is not None:
            if trusted:
                self._on_tpdo(entry, msg.data, ts)
            else:
                self._on_unplaced_tpdo(entry[0] - 1, t - ts)
        elif cid == SYNC_COB_ID:
            self._on_bus_sync(msg, t, ts if trusted else None)
        elif cid in self._leg_of_emcy:
            self._on_emcy(self._leg_of_emcy[cid], msg.data, ts if trusted else None)
        if trusted:  # an untrusted bus time must not close sets
            with self._lock:
                self._close_until(ts)
        if self._bus_state == BUS_OFF:
            with self._lock:
                # A frame came through: the controller is receiving again.
                self._bus_state, self._bus_detail = BUS_ACTIVE, ""
                self._note(
                    "recovered",
                    f"{self._bus_name} recovered from BUS-OFF (frames arrive again); sets taken "
                    "while it was off are flagged",
                )

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
            if s.arrival[k] == s.arrival[k]:
                s.faults[f"twice{k}"] = (
                    f"{self._names[k]} sent two positions for SYNC {s.counter} on {self._bus_name} (a "
                    "late frame from the previous SYNC, or a cyclic TPDO?) — set flagged, the later "
                    f"one kept; check its TPDO{self.config.tpdo} transmission type is 1 (every SYNC)"
                )
            else:
                s.n += 1
            delay = ts - s.t_bus
            s.readings[k] = mm
            s.arrival[k] = s.t_sync + delay
            if delay > self._deadline:
                s.faults[f"late{k}"] = (
                    f"{self._names[k]} position arrived {delay * 1e3:.1f} ms after SYNC {s.counter} "
                    f"(limit {self._deadline * 1e3:.1f} ms) on {self._bus_name}: timing jitter or bus "
                    "overload — set flagged; if it repeats reduce the bus load or raise max_tpdo_delay_s"
                )
            self._cond.notify_all()

    def _on_unplaced_tpdo(self, k: int, lag: float) -> None:
        """A position whose bus time is not trusted (it arrived ``lag`` s after it): no SYNC
        window can be told for it, so it is discarded and the newest set flagged."""
        with self._lock:
            self._frames[k] += 1
            off = min(self._offset_min) - lag
            self._note(
                f"stamp{k}",
                f"{self._names[k]} sent a position stamped {off:+.3f} s off the clock of "
                f"{self._bus_name} (against the host clock) — no SYNC can be told for it, so it "
                "was discarded and this set flagged; a jump of the interface's clock or a corrupt "
                "timestamp",
            )

    def _on_bus_sync(self, msg: can.Message, t: float, ts: float | None) -> None:
        """A SYNC on the bus at bus time ``ts`` (None: not trusted, placed by arrival ``t``)."""
        counter = msg.data[0] if len(msg.data) >= 1 else 0
        with self._lock:
            if self._producing:
                if msg.is_rx:
                    self._foreign_syncs += 1
                    self._note(
                        "foreign_sync",
                        f"another SYNC producer is on {self._bus_name} (SYNC not sent by hexcal) — "
                        "the encoders answer both; switch it off, or set sync_period_s = 0 to follow it",
                    )
                return
            if ts is None:
                self._open_set(t, self._to_bus(t), counter)
                self._open[-1].faults["sync_stamp"] = (
                    f"SYNC {counter} on {self._bus_name} carried a timestamp off the bus clock: "
                    "placed by its arrival instead, so its positions may be misplaced — set flagged"
                )
                return
            self._open_set(ts + min(self._offset_min), ts, counter)

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
            info = configure_node(net, self.config.legs[k], self.config)
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
            # Open the set before sending: the answers may arrive before send() returns.
            t = time.monotonic()
            self._open_set(t, self._to_bus(t), self._sync_counter)
        try:
            # No counter byte for nodes whose 0x1019 is 0: they answer one with EMCY 0x8240.
            net.sync.transmit(self._sync_counter or None)
        except (can.CanError, OSError) as exc:
            with self._lock:
                self._bus_state, self._bus_detail = BUS_ERROR, f"sending SYNC failed: {exc}"
                self._note("send", self._bus_message())
                self._close_all()
            return
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
                # the first need their deadline before the next SYNC goes on the bus.
                next_sync = max(next_sync + period, now + self._deadline)
                behind = time.monotonic() - next_sync
                if behind > period:  # a stall (busy machine): skip, do not burst SYNCs
                    missed = int(behind / period)
                    next_sync += missed * period
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
            while self._open and now - self._open[0].t_sync > self._close_after:
                self._close(now)
            for k in range(6):
                if not self._silent[k] and self._age(k, now) > self.config.heartbeat_timeout_s:
                    self._silent[k] = True
                    log.warning("%s", self._silent_message(k, now))
        if self._polls_state and now >= self._next_state_poll and self._network is not None:
            self._next_state_poll = now + 0.1
            try:
                st = self._network.bus.state
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
