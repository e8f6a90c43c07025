"""The instruments' noise (``instruments.json`` of docs/formats.md).

One standard deviation each, as the instruments' specifications or a repeatability test state:
tracker position (mm, per axis), tracker orientation (deg, a small rotation about each axis of the
platform frame) and encoder reading (mm). It sets the noise floor against which a model's
residual is judged. Unknown keys are kept and written back, at every level.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from hexcal.fileio import write_text_atomic

# strict: a JSON string "0.01" or a boolean is a mistake in the file, not a number to coerce.
# allow_inf_nan=False: json.loads accepts NaN/Infinity, which would poison every weight.
Sigma = Annotated[float, Field(gt=0, strict=True, allow_inf_nan=False)]


class InstrumentsError(ValueError):
    """instruments.json could not be read; the message names the file and the field."""

    def __init__(self, message: str, path: str | Path | None = None):
        self.path: str | None = None if path is None else str(path)
        super().__init__(message)


class TrackerNoise(BaseModel):
    """Tracker noise, one standard deviation: position mm (per axis), orientation deg."""

    model_config = ConfigDict(extra="allow")
    position_sigma_mm: Sigma
    orientation_sigma_deg: Sigma


class EncoderNoise(BaseModel):
    """Encoder noise, one standard deviation of a reading, mm."""

    model_config = ConfigDict(extra="allow")
    reading_sigma_mm: Sigma


class Instruments(BaseModel):
    """instruments.json: the tracker's and the encoders' noise. Unknown keys are kept."""

    model_config = ConfigDict(extra="allow")
    tracker: TrackerNoise
    encoders: EncoderNoise

    @property
    def sigma_position_mm(self) -> float:
        """Tracker position noise, mm, one standard deviation per axis."""
        return float(self.tracker.position_sigma_mm)

    @property
    def sigma_orientation_rad(self) -> float:
        """Tracker orientation noise, rad, one standard deviation about each platform axis."""
        return math.radians(self.tracker.orientation_sigma_deg)

    @property
    def sigma_reading_mm(self) -> float:
        """Encoder reading noise, mm, one standard deviation."""
        return float(self.encoders.reading_sigma_mm)

    def to_json(self) -> str:
        """instruments.json text (indent 2), unknown keys included."""
        return json.dumps(self.model_dump(), indent=2) + "\n"


def _hint(field: str) -> str:
    if field.endswith("_deg"):
        return "give one standard deviation in degrees, > 0"
    if field.endswith("_mm"):
        return "give one standard deviation in millimetres, > 0"
    return 'see docs/formats.md: {"tracker": {...}, "encoders": {...}}'


def load_instruments(path: str | Path) -> Instruments:
    """Read instruments.json; errors (:class:`InstrumentsError`) name the file and the field."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InstrumentsError(
            f"{path}: no such file; check the path to the instruments' noise", path
        ) from None
    except UnicodeDecodeError:
        raise InstrumentsError(f"{path}: not UTF-8 text; save the file as UTF-8", path) from None
    except OSError as exc:
        raise InstrumentsError(f"{path}: cannot be read ({exc.strerror})", path) from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InstrumentsError(
            f"{path}: line {exc.lineno}, column {exc.colno}: not valid JSON ({exc.msg})", path
        ) from None
    try:
        return Instruments.model_validate(data)
    except ValidationError as exc:
        lines = []
        for err in exc.errors(include_url=False):
            field = ".".join(str(p) for p in err["loc"]) or "(top level)"
            got = "" if err["type"] == "missing" else f" (got {err['input']!r})"
            lines.append(f"{path}: field {field}: {err['msg']}{got}; {_hint(field)}")
        raise InstrumentsError("\n".join(lines), path) from None


def save_instruments(inst: Instruments, path: str | Path) -> None:
    """Write instruments.json atomically (temp file in the same folder, fsync, rename)."""
    write_text_atomic(path, inst.to_json())
