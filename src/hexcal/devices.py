"""The rig's device configuration (one TOML file, validated by pydantic) and the device check.

```toml
[tracker]
kind = "ndi"                 # NDI Combined API (Polaris / Aurora); "line" for the plain-text protocol
url = "/dev/ttyUSB0"         # anything serial.serial_for_url opens: a device, socket://host:port, a mock URL
baudrate = 115200

[can]                        # python-can bus and the six CiA 406 encoder nodes
interface = "socketcan"
channel = "can0"
bitrate = 1000000
sync_period_s = 0.01
heartbeat_timeout_s = 0.5
[[can.legs]]
leg = 1
node_id = 0x21
counts_per_mm = 1000.0
sign = 1
zero_mm = 0.0
# ... legs 2 to 6

[still]                      # the still window a pose is recorded from
duration_s = 0.5
max_position_drift_mm = 0.05   # how far the mean may move between the window's halves
max_angle_drift_deg = 0.01
max_reading_drift_mm = 0.01
max_fault_share = 0.0          # share of flagged samples (CRC error, late CAN set...) a pose may
                               # leave out; 0: any flagged sample refuses the pose
```
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import AliasChoices, BaseModel, ConfigDict, Field, ValidationError

from hexcal.acquisition import StillWindow
from hexcal.drivers.can_config import CanBusConfig, default_can_config
from hexcal.validation import format_validation_error


class DevicesConfigError(ValueError):
    """The device configuration file is unreadable; the message names the file and field."""


class TrackerConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    kind: Literal["ndi", "line"] = "ndi"
    url: str = Field(..., description="a device path, socket://host:port or a mock URL")
    baudrate: int = Field(115200, gt=0)
    timeout_s: float = Field(1.0, gt=0)
    #: "break" for a real serial port, "command" (RESET:0) where a BREAK cannot pass (a pty, a
    #: socket), "auto" to try the BREAK first.
    reset: Literal["auto", "break", "command"] = "auto"


class StillConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    duration_s: float = Field(0.5, gt=0)
    # The *_spread_* names of schema 1 files (before motion was judged by drift) still load.
    max_position_drift_mm: float = Field(
        0.05, gt=0, validation_alias=AliasChoices("max_position_drift_mm", "max_position_spread_mm")
    )
    max_angle_drift_deg: float = Field(
        0.01, gt=0, validation_alias=AliasChoices("max_angle_drift_deg", "max_angle_spread_deg")
    )
    max_reading_drift_mm: float = Field(
        0.01, gt=0, validation_alias=AliasChoices("max_reading_drift_mm", "max_reading_spread_mm")
    )
    min_tracker_samples: int = Field(5, ge=1)
    min_leg_samples: int = Field(5, ge=1)
    # 0: a pose with any flagged sample is refused; a lab whose devices glitch now and then
    # may allow a share, left out of the average and noted with the pose.
    max_fault_share: float = Field(0.0, ge=0, le=1)

    def window(self) -> StillWindow:
        return StillWindow(**self.model_dump())


class DevicesConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    tracker: TrackerConfig
    can: CanBusConfig = Field(default_factory=default_can_config)
    still: StillConfig = Field(default_factory=StillConfig)


def load_devices_config(path: str | Path) -> DevicesConfig:
    """Read the TOML device configuration; errors name the file and the field."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise DevicesConfigError(
            f"{path}: no such file; pass the rig's device configuration with --config"
        ) from None
    try:
        try:
            import tomllib
        except ModuleNotFoundError:  # Python 3.10
            import tomli as tomllib
        data = tomllib.loads(text)
    except ValueError as exc:
        raise DevicesConfigError(f"{path}: not valid TOML ({exc})") from None
    try:
        return DevicesConfig.model_validate(data)
    except ValidationError as exc:
        raise DevicesConfigError(format_validation_error(exc, str(path))) from None
