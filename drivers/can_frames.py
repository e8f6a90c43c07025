"""What the leg encoders' CAN frames mean to the driver: CiA 301 NMT codes, SocketCAN error
classes and the bus states they lead to, the position TPDO decoder (:class:`TpdoDecoder`), the
reading set answering one SYNC (:class:`ReadingSet`) and the errors the driver raises.
:mod:`hexcal.drivers.can_encoders` re-exports every public name."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import can
import numpy as np

from hexcal.acquire.acquisition import LegSample
from hexcal.drivers.can_config import CanBusConfig, LegEncoderConfig
from hexcal.drivers.can_nodes import NodeInfo
from hexcal.errors import DeviceError

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
class EncoderError(DeviceError):
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
        # legs 0 (not a position TPDO) index leg 1 here; their readings are set to NaN below.
        unsigned = ~np.array(self.signed)[np.maximum(legs, 1) - 1]
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
    ``reboots``: (6,) how many times each leg's node had rebooted (boot-up while running) when
    the set closed: a reading after a reboot may have lost the encoder's zero (its preset).
    """

    sync_counter: int
    t_sync: float
    readings_mm: np.ndarray
    arrival: np.ndarray
    complete: bool
    faults: list[str] = field(default_factory=list)
    index: int = 0
    reboots: tuple[int, ...] = (0, 0, 0, 0, 0, 0)

    def to_leg_sample(self) -> LegSample:
        """This set as the acquisition's :class:`~hexcal.acquire.acquisition.LegSample`, stamped with the
        SYNC time (the instant the six encoders latched their positions)."""
        faults = tuple(self.faults)
        if not self.complete and not faults:  # cannot happen by construction; never hide it
            faults = ("leg encoder reading set incomplete",)
        return LegSample(self.t_sync, self.readings_mm.copy(), faults, self.reboots)
