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
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from hexcal.errors import InputError
from hexcal.io.fileio import write_text_atomic
from hexcal.io.safe_read import read_json
from hexcal.io.validation import format_validation_error

#: Largest σ accepted, mm (1 m) and deg (half a turn): beyond them the noise is no longer a
#: small perturbation, and squaring σ (the weights) must stay far from overflow.
MAX_SIGMA_MM = 1e3
MAX_SIGMA_DEG = 180.0

# strict: a JSON string "0.01" or a boolean is a mistake in the file, not a number to coerce.
# allow_inf_nan=False: json.loads accepts NaN/Infinity, which would poison every weight.
SigmaMm = Annotated[float, Field(gt=0, le=MAX_SIGMA_MM, strict=True, allow_inf_nan=False)]
SigmaDeg = Annotated[float, Field(gt=0, le=MAX_SIGMA_DEG, strict=True, allow_inf_nan=False)]


class InstrumentsError(InputError):
    """instruments.json could not be read; the message names the file and the field."""

    def __init__(self, message: str, path: str | Path | None = None):
        self.path: str | None = None if path is None else str(path)
        super().__init__(message)


class TrackerNoise(BaseModel):
    """Tracker noise, one standard deviation: position mm (per axis), orientation deg."""

    model_config = ConfigDict(extra="allow")
    position_sigma_mm: SigmaMm
    orientation_sigma_deg: SigmaDeg


class EncoderNoise(BaseModel):
    """Encoder noise, one standard deviation of a reading, mm."""

    model_config = ConfigDict(extra="allow")
    reading_sigma_mm: SigmaMm


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

    def stated_source(self) -> str | None:
        """The optional ``source`` key: where the figures came from, when the file (or the
        hexcal step that estimated them) says."""
        value = (self.model_extra or {}).get("source")
        return None if value is None else str(value)

    def to_json(self) -> str:
        """instruments.json text (indent 2), unknown keys included."""
        return json.dumps(self.model_dump(), indent=2, allow_nan=False) + "\n"


def _hint(loc: tuple[Any, ...], kind: str) -> str:
    field = str(loc[-1]) if loc else ""
    if field.endswith("_deg"):
        return f"give one standard deviation in degrees, > 0 and ≤ {MAX_SIGMA_DEG:g}"
    if field.endswith("_mm"):
        return f"give one standard deviation in millimetres, > 0 and ≤ {MAX_SIGMA_MM:g}"
    return 'see docs/formats.md: {"tracker": {...}, "encoders": {...}}'


def load_instruments(path: str | Path) -> Instruments:
    """Read instruments.json; errors (:class:`InstrumentsError`) name the file and the field."""
    path = Path(path)
    data = read_json(path, "instruments", lambda message: InstrumentsError(message, path))
    try:
        return Instruments.model_validate(data)
    except ValidationError as exc:
        text = format_validation_error(exc, str(path), data, hint=_hint)
        raise InstrumentsError(text, path) from None


def save_instruments(inst: Instruments, path: str | Path) -> None:
    """Write instruments.json atomically (temp file in the same folder, fsync, rename)."""
    write_text_atomic(path, inst.to_json())
