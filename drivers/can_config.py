"""Configuration of the CAN leg encoders: the bus and, per leg, the CANopen node and its scaling.

Six CiA 406 encoder nodes, one per leg. hexcal sets each up over SDO at start
(:mod:`hexcal.drivers.can_nodes`) to send its position (object 0x6004, counts) in TPDO ``tpdo``
(2 by default: the synchronous TPDO of CiA 406) on every SYNC; the driver turns counts into a
reading in mm:

    reading_mm = sign × counts / counts_per_mm + zero_mm

so ``zero_mm`` is the reading at zero counts and ``sign`` flips an encoder mounted the other way
round. The python-can ``interface`` and ``channel`` come from here (``socketcan``/``can0``,
``pcan``/``PCAN_USBBUS1``, ``kvaser``/``0``, ``virtual``/any name...), so the driver never
changes between the rig and the tests.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from hexcal.drivers.limits import MAX_TIMEOUT_S
from hexcal.errors import InputError
from hexcal.io.validation import format_validation_error

#: COB-ID bases of the CANopen services the driver uses (CiA 301 predefined connection set).
NMT_COB_ID = 0x000
SYNC_COB_ID = 0x080
TPDO1_BASE = 0x180
EMCY_BASE = 0x080
HEARTBEAT_BASE = 0x700


def tpdo_cob_id(n: int, node_id: int) -> int:
    """The predefined COB-ID of TPDO ``n`` (1..4) of node ``node_id``: 0x180 + 0x100·(n − 1)."""
    return TPDO1_BASE + 0x100 * (n - 1) + node_id


_Finite = Annotated[float, Field(allow_inf_nan=False)]


class CanConfigError(InputError):
    """A CAN configuration file could not be read; the message names the file and the field."""


class LegEncoderConfig(BaseModel):
    """One leg's encoder: its CANopen node and how its counts become mm.

    ``leg`` 1..6; ``node_id`` 1..127 (TPDO1 COB-ID 0x180 + node, heartbeat 0x700 + node);
    ``counts_per_mm`` > 0; ``sign`` +1 or −1; ``zero_mm`` the reading at zero counts (mm).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    leg: int = Field(ge=1, le=6, strict=True)
    node_id: int = Field(ge=1, le=127, strict=True)
    counts_per_mm: float = Field(gt=0, allow_inf_nan=False)
    sign: int = Field(default=1, strict=True)
    zero_mm: _Finite = 0.0
    #: This node's EDS when it differs from the bus's (a path; relative to the rig file).
    eds: str | None = None

    @field_validator("sign")
    @classmethod
    def _sign_is_unit(cls, v: int) -> int:
        # A scale of 2 or 0 here would be a counts_per_mm mistake in disguise: refuse it.
        if v not in (1, -1):
            raise ValueError(f"sign must be +1 or -1 (got {v}); put the scale in counts_per_mm")
        return v

    @property
    def tpdo1_cob_id(self) -> int:
        return TPDO1_BASE + self.node_id

    def tpdo_cob_id(self, n: int) -> int:
        """TPDO ``n``'s COB-ID for this node (predefined connection set)."""
        return tpdo_cob_id(n, self.node_id)

    @property
    def emcy_cob_id(self) -> int:
        return EMCY_BASE + self.node_id

    @property
    def heartbeat_cob_id(self) -> int:
        return HEARTBEAT_BASE + self.node_id

    @property
    def name(self) -> str:
        """How messages name this encoder: ``leg 3 encoder (node 0x23)``."""
        return f"leg {self.leg} encoder (node 0x{self.node_id:02X})"

    def counts_to_mm(self, counts: int) -> float:
        """A position in counts (0x6004) as a reading in mm."""
        return self.sign * counts / self.counts_per_mm + self.zero_mm

    def mm_to_counts(self, reading_mm: float) -> int:
        """The inverse of :meth:`counts_to_mm`, rounded to the nearest count (what a node sends)."""
        return round((reading_mm - self.zero_mm) * self.counts_per_mm * self.sign)


def default_legs(
    first_node_id: int = 0x21, counts_per_mm: float = 1000.0
) -> list[LegEncoderConfig]:
    """Six legs on consecutive node ids (0x21..0x26 by default), same scale, sign +1, zero 0."""
    return [
        LegEncoderConfig(leg=k, node_id=first_node_id + k - 1, counts_per_mm=counts_per_mm)
        for k in range(1, 7)
    ]


#: The shortest SYNC period hexcal produces, s: the SYNC and six 8-byte answers take about
#: 0.7 ms on the wire at 1 Mbit/s.
MIN_SYNC_PERIOD_S = 1e-3


class CanBusConfig(BaseModel):
    """The bus and its six leg encoders.

    ``interface``/``channel``/``bitrate`` go to ``can.Bus``. ``sync_period_s`` > 0: the driver
    produces SYNC at that period (s); 0: another master produces it and the driver follows.
    ``heartbeat_timeout_s``: a node whose heartbeat is older than this is reported silent.
    ``max_tpdo_delay_s``: a position arriving later than this after its SYNC flags the set
    (timing jitter); None means half the SYNC period (5 ms when the driver does not produce
    SYNC). ``legs``: exactly six, legs 1..6 once each, node ids unique; kept sorted by leg.
    Every duration is finite and at most :data:`~hexcal.drivers.limits.MAX_TIMEOUT_S` (60 s):
    the driver waits on them, and a wait must end.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    interface: str = Field(default="virtual", min_length=1)
    channel: str = Field(default="hexcal", min_length=1)
    bitrate: int = Field(default=1_000_000, gt=0, le=1_000_000)
    sync_period_s: float = Field(default=0.01, ge=0, le=MAX_TIMEOUT_S, allow_inf_nan=False)
    heartbeat_timeout_s: float = Field(default=0.5, gt=0, le=MAX_TIMEOUT_S, allow_inf_nan=False)
    max_tpdo_delay_s: float | None = Field(
        default=None, gt=0, le=MAX_TIMEOUT_S, allow_inf_nan=False
    )
    legs: list[LegEncoderConfig] = Field(default_factory=default_legs)
    #: Set the nodes up over SDO at start (module :mod:`hexcal.drivers.can_nodes`); False for
    #: nodes configured by other means (the driver then only NMT-starts them).
    configure: bool = True
    #: The EDS of the encoders (a path, relative to the rig file); None: hexcal's generic
    #: CiA 406 EDS.
    eds: str | None = None
    #: The TPDO (1..4) hexcal maps 0x6004 into and sets to transmit on every SYNC. CiA 406
    #: makes TPDO2 the synchronous one and TPDO1 cyclic.
    tpdo: int = Field(default=2, ge=1, le=4)
    #: The encoders' other TPDOs: "disable" them (their cyclic frames only load the bus) or
    #: "keep" them as they are (another master uses them).
    other_tpdos: Literal["disable", "keep"] = "disable"
    #: The heartbeat producer time written to each node (0x1017), ms; None: a quarter of
    #: heartbeat_timeout_s.
    heartbeat_ms: int | None = Field(default=None, ge=1, le=65535)
    #: The SYNC counter overflow (0x1019) written to each node: 0 = SYNC without a counter,
    #: 2..240 = with one. None: read it from the nodes and send SYNC as they expect.
    sync_counter: int | None = Field(default=None, ge=0, le=240)
    #: How long to wait for an SDO answer, s.
    sdo_timeout_s: float = Field(default=0.3, gt=0, le=MAX_TIMEOUT_S, allow_inf_nan=False)
    #: Further keyword arguments for ``can.Bus``, as the interface documents them (e.g.
    #: ``port`` of python-can's udp_multicast, ``fd`` of an adapter).
    bus_options: dict[str, str | int | float | bool] = Field(default_factory=dict)

    @field_validator("bus_options")
    @classmethod
    def _options_not_the_fields(
        cls, v: dict[str, str | int | float | bool]
    ) -> dict[str, str | int | float | bool]:
        taken = sorted(set(v) & {"interface", "channel", "bitrate", "receive_own_messages"})
        if taken:
            raise ValueError(
                f"bus_options may not set {', '.join(taken)}: give interface, channel and bitrate "
                "as the [can] table's own keys (hexcal sets receive_own_messages itself)"
            )
        return v

    @field_validator("legs")
    @classmethod
    def _six_distinct_legs(cls, legs: list[LegEncoderConfig]) -> list[LegEncoderConfig]:
        if len(legs) != 6:
            raise ValueError(f"need exactly 6 legs (one encoder per leg), got {len(legs)}")
        seen: dict[int, int] = {}
        for cfg in legs:
            if cfg.leg in seen:
                raise ValueError(f"leg {cfg.leg} is listed twice; list legs 1..6 once each")
            seen[cfg.leg] = cfg.node_id
        owners: dict[int, int] = {}
        for cfg in legs:
            if cfg.node_id in owners:
                raise ValueError(
                    f"node id 0x{cfg.node_id:02X} is used by legs {owners[cfg.node_id]} and {cfg.leg}; "
                    "every encoder needs its own node id"
                )
            owners[cfg.node_id] = cfg.leg
        # Legs are 1..6 and distinct, so sorting puts leg k at index k − 1 everywhere.
        return sorted(legs, key=lambda c: c.leg)

    @field_validator("sync_counter")
    @classmethod
    def _sync_counter_allowed(cls, v: int | None) -> int | None:
        if v == 1:
            raise ValueError(
                "sync_counter 1 is not allowed by CiA 301: give 0 (SYNC without a counter) or 2..240"
            )
        return v

    @model_validator(mode="after")
    def _heartbeat_within_supervision(self) -> CanBusConfig:
        if self.heartbeat_ms is not None and self.heartbeat_ms / 1000 >= self.heartbeat_timeout_s:
            raise ValueError(
                f"heartbeat_ms ({self.heartbeat_ms} ms) must be shorter than heartbeat_timeout_s "
                f"({self.heartbeat_timeout_s:g} s), or every node is reported silent"
            )
        return self

    @property
    def heartbeat_period_ms(self) -> int:
        """The heartbeat producer time hexcal writes to each node, ms."""
        if self.heartbeat_ms is not None:
            return self.heartbeat_ms
        return max(1, min(65535, round(self.heartbeat_timeout_s * 1000 / 4)))

    @field_validator("sync_period_s")
    @classmethod
    def _a_period_the_bus_can_carry(cls, v: float) -> float:
        if 0 < v < MIN_SYNC_PERIOD_S:
            raise ValueError(
                f"sync_period_s is 0 (another master sends SYNC) or at least "
                f"{MIN_SYNC_PERIOD_S * 1e3:g} ms (six answers take about 0.7 ms at 1 Mbit/s), "
                f"not {v:g} s"
            )
        return v

    @model_validator(mode="after")
    def _delay_below_period(self) -> CanBusConfig:
        if (
            self.max_tpdo_delay_s is not None
            and self.sync_period_s > 0
            and self.max_tpdo_delay_s >= self.sync_period_s
        ):
            raise ValueError(
                f"max_tpdo_delay_s ({self.max_tpdo_delay_s:g} s) must be shorter than sync_period_s "
                f"({self.sync_period_s:g} s): a position later than one SYNC period cannot be told "
                "from the next SYNC's"
            )
        return self

    @property
    def bus_name(self) -> str:
        """How messages name the bus: ``CAN socketcan channel 'can0'``."""
        return f"CAN {self.interface} channel '{self.channel}'"

    @property
    def tpdo_deadline_s(self) -> float:
        """The effective ``max_tpdo_delay_s``, s."""
        if self.max_tpdo_delay_s is not None:
            return self.max_tpdo_delay_s
        return 0.5 * self.sync_period_s if self.sync_period_s > 0 else 0.005

    def relative_to(self, base: Path) -> CanBusConfig:
        """This configuration with its EDS paths taken relative to ``base`` (the rig file's
        folder) made absolute."""

        def resolve(p: str | None) -> str | None:
            if p is None or Path(p).is_absolute():
                return p
            return str(base / p)

        legs = [leg.model_copy(update={"eds": resolve(leg.eds)}) for leg in self.legs]
        return self.model_copy(update={"eds": resolve(self.eds), "legs": legs})

    def leg(self, k: int) -> LegEncoderConfig:
        """Leg k's encoder (k in 1..6)."""
        return self.legs[k - 1]

    def bus_kwargs(self) -> dict[str, Any]:
        """Keyword arguments for ``can.Bus``."""
        return {
            **self.bus_options,
            "interface": self.interface,
            "channel": self.channel,
            "bitrate": self.bitrate,
        }


def default_can_config(**overrides: object) -> CanBusConfig:
    """The default configuration (virtual bus 'hexcal', nodes 0x21..0x26, 1000 counts/mm),
    with any field overridden by keyword."""
    return CanBusConfig.model_validate(overrides)


def load_can_config(path: str | Path) -> CanBusConfig:
    """Read a CAN configuration from JSON (``.json``) or TOML (anything else); errors name the
    file and the field and say what to fix."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise CanConfigError(f"{path}: no such file") from None
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(raw)
        else:
            if sys.version_info >= (3, 11):
                import tomllib
            else:  # Python 3.10
                import tomli as tomllib
            data = tomllib.loads(raw.decode("utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise CanConfigError(f"{path}: not valid {path.suffix or 'TOML'} ({exc})") from None
    except RecursionError:  # both parsers recurse per nesting level: [[[[... is no configuration
        raise CanConfigError(
            f"{path}: not valid {path.suffix or 'TOML'} (nested too deeply to be a configuration)"
        ) from None
    try:
        return CanBusConfig.model_validate(data).relative_to(path.parent)
    except ValidationError as exc:
        raise CanConfigError(format_validation_error(exc, str(path))) from None


__all__ = [
    "EMCY_BASE",
    "HEARTBEAT_BASE",
    "NMT_COB_ID",
    "SYNC_COB_ID",
    "TPDO1_BASE",
    "CanBusConfig",
    "CanConfigError",
    "LegEncoderConfig",
    "default_can_config",
    "default_legs",
    "format_validation_error",
    "load_can_config",
    "tpdo_cob_id",
]
