"""The rig's device configuration (one TOML file, validated by pydantic) and the device check.

A commented example for an NDI Polaris on USB serial and six CiA 406 encoders on SocketCAN or
a PCAN / Kvaser adapter is ``examples/rig.toml``; its tables:

- ``[tracker]``: ``kind`` ("ndi" or "line"), ``url`` (anything ``serial.serial_for_url``
  opens), ``baudrate``, ``timeout_s``, ``reset``;
- ``[can]``: the python-can bus (``interface``, ``channel``, ``bitrate``), the SYNC period and
  heartbeat supervision, what hexcal sets on each encoder at start (``configure``, ``eds``,
  ``tpdo``, ``other_tpdos``, ``heartbeat_ms``, ``sync_counter``, ``sdo_timeout_s``; see
  :mod:`hexcal.drivers.can_nodes`) and ``[[can.legs]]`` (``leg``, ``node_id``,
  ``counts_per_mm``, ``sign``, ``zero_mm``, ``eds``);
- ``[still]``: the still window a pose is recorded from;
- ``effects``: Python files defining effects beyond the catalogue, which ``hexcal run`` loads
  for the text UI (docs/effects.md). They are the lab's own code, named in the lab's own rig
  file; a session stores the rig's devices but never these paths.

Paths in the file (EDS, effects) are relative to it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import AliasChoices, BaseModel, ConfigDict, Field, ValidationError, field_validator

from hexcal.acquire.acquisition import StillWindow
from hexcal.drivers.can_config import CanBusConfig, default_can_config
from hexcal.errors import InputError
from hexcal.io.safe_read import read_toml
from hexcal.io.validation import format_validation_error

#: Longest wait for a device, s: a timeout beyond it is a typo (and an infinite one hangs).
MAX_TIMEOUT_S = 60.0
#: Fastest serial line, baud (the NDI trackers top out at 1.2 Mbaud; USB adapters at 12).
MAX_BAUDRATE = 12_000_000
#: Largest drift limit of the still window: mm and deg.
MAX_DRIFT_MM = 100.0
MAX_DRIFT_DEG = 180.0
#: Most samples a still window may require.
MAX_WINDOW_SAMPLES = 100_000
#: Limits on the CAN encoders' numbers (checked here until hexcal.drivers.can_config holds
#: them): scale, counts per mm; zero, mm.
MAX_COUNTS_PER_MM = 1e9
MAX_ZERO_MM = 1e6

Timeout = Annotated[float, Field(gt=0, le=MAX_TIMEOUT_S, allow_inf_nan=False)]


class DevicesConfigError(InputError):
    """The device configuration file is unreadable; the message names the file and field."""


class TrackerConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    kind: Literal["ndi", "line"] = "ndi"
    url: str = Field(
        ..., min_length=1, description="a device path, socket://host:port or a mock URL"
    )
    baudrate: int = Field(115200, gt=0, le=MAX_BAUDRATE)
    #: How long to wait for the tracker's reply, s.
    timeout_s: Timeout = 1.0
    #: "break" for a real serial port, "command" (RESET:0) where a BREAK cannot pass (a pty, a
    #: socket), "auto" to try the BREAK first.
    reset: Literal["auto", "break", "command"] = "auto"


class StillConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    #: How long the platform must be still, s.
    duration_s: Timeout = 0.5
    # The *_spread_* names of schema 1 files (before motion was judged by drift) still load.
    max_position_drift_mm: float = Field(
        0.05,
        gt=0,
        le=MAX_DRIFT_MM,
        allow_inf_nan=False,
        validation_alias=AliasChoices("max_position_drift_mm", "max_position_spread_mm"),
    )
    max_angle_drift_deg: float = Field(
        0.01,
        gt=0,
        le=MAX_DRIFT_DEG,
        allow_inf_nan=False,
        validation_alias=AliasChoices("max_angle_drift_deg", "max_angle_spread_deg"),
    )
    max_reading_drift_mm: float = Field(
        0.01,
        gt=0,
        le=MAX_DRIFT_MM,
        allow_inf_nan=False,
        validation_alias=AliasChoices("max_reading_drift_mm", "max_reading_spread_mm"),
    )
    min_tracker_samples: int = Field(5, ge=1, le=MAX_WINDOW_SAMPLES)
    min_leg_samples: int = Field(5, ge=1, le=MAX_WINDOW_SAMPLES)
    # 0: a pose with any flagged sample is refused; a lab whose devices glitch now and then
    # may allow a share, left out of the average and noted with the pose.
    max_fault_share: float = Field(0.0, ge=0, le=1, allow_inf_nan=False)

    def window(self) -> StillWindow:
        return StillWindow(**self.model_dump())


#: Most effect files a rig file may list.
MAX_EFFECT_FILES = 100


class DevicesConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    tracker: TrackerConfig
    can: CanBusConfig = Field(default_factory=default_can_config)
    still: StillConfig = Field(default_factory=StillConfig)
    #: Effect files for the text UI, relative to the rig file. Not stored with a session (it
    #: is code the lab runs, not a record of the devices), so ``exclude``.
    effects: list[Path] = Field(default_factory=list, max_length=MAX_EFFECT_FILES, exclude=True)

    @field_validator("can")
    @classmethod
    def _can_in_range(cls, can: CanBusConfig) -> CanBusConfig:
        # CanBusConfig (hexcal.drivers) holds its numbers finite and its durations to 60 s;
        # the encoders' scale and zero are held to a range here.
        problems = []
        for leg in can.legs:  # sorted by leg: name the leg, not the position in the file
            if leg.counts_per_mm > MAX_COUNTS_PER_MM:
                problems.append(
                    f"leg {leg.leg}'s counts_per_mm is {leg.counts_per_mm:g}; give at most "
                    f"{MAX_COUNTS_PER_MM:g} counts per mm"
                )
            if abs(leg.zero_mm) > MAX_ZERO_MM:
                problems.append(
                    f"leg {leg.leg}'s zero_mm is {leg.zero_mm:g} mm; give at most ±{MAX_ZERO_MM:g} mm"
                )
        if problems:
            raise ValueError("; ".join(problems))
        return can


def _error(message: str) -> DevicesConfigError:
    return DevicesConfigError(message)


def load_devices_config(path: str | Path) -> DevicesConfig:
    """Read the TOML device configuration; errors name the file and the field."""
    data = read_toml(path, "devices", _error)
    try:
        cfg = DevicesConfig.model_validate(data)
    except ValidationError as exc:
        raise DevicesConfigError(format_validation_error(exc, str(path), data)) from None
    # EDS and effect paths in the file are relative to it.
    here = Path(path).parent
    effects = [p if p.is_absolute() else here / p for p in cfg.effects]
    return cfg.model_copy(update={"can": cfg.can.relative_to(here), "effects": effects})
