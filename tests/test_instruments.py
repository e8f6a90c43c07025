"""instruments.json: loading, validation messages, lossless atomic save."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import pytest

from hexcal.model.instruments import (
    EncoderNoise,
    Instruments,
    InstrumentsError,
    TrackerNoise,
    load_instruments,
    save_instruments,
)

EXAMPLE = Path(__file__).parents[1] / ".." / "shared" / "examples" / "left-hand"
GOOD = {
    "tracker": {"position_sigma_mm": 0.01, "orientation_sigma_deg": 0.002},
    "encoders": {"reading_sigma_mm": 0.002},
}


def write_json(tmp_path: Path, data: object, name: str = "instruments.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(data), encoding="utf-8")
    return path


def test_load_and_sigmas(tmp_path: Path) -> None:
    inst = load_instruments(write_json(tmp_path, GOOD))
    assert inst.sigma_position_mm == 0.01
    assert math.isclose(inst.sigma_orientation_rad, math.radians(0.002))
    assert inst.sigma_reading_mm == 0.002


def test_example_loads() -> None:
    path = EXAMPLE / "instruments.json"
    if not path.is_file():
        pytest.skip(f"shared example not present at {EXAMPLE}")
    inst = load_instruments(path)
    assert inst.sigma_position_mm > 0 and inst.sigma_reading_mm > 0


def test_round_trip_keeps_unknown_keys(tmp_path: Path) -> None:
    data = {
        **GOOD,
        "tracker": {**GOOD["tracker"], "model": "AT960"},
        "note": "from the 2024 repeatability test",
    }
    inst = load_instruments(write_json(tmp_path, data, "in.json"))
    out = tmp_path / "out.json"
    save_instruments(inst, out)
    assert json.loads(out.read_text(encoding="utf-8")) == data
    assert load_instruments(out) == inst


def test_save_is_atomic(tmp_path: Path) -> None:
    inst = Instruments(
        tracker=TrackerNoise(position_sigma_mm=0.02, orientation_sigma_deg=0.01),
        encoders=EncoderNoise(reading_sigma_mm=0.001),
    )
    path = tmp_path / "instruments.json"
    path.write_text("old", encoding="utf-8")
    save_instruments(inst, path)
    assert os.listdir(tmp_path) == ["instruments.json"]
    assert load_instruments(path) == inst


@pytest.mark.parametrize(
    ("data", "field", "text"),
    [
        (
            {**GOOD, "tracker": {**GOOD["tracker"], "position_sigma_mm": -1}},
            "position_sigma_mm",
            "greater than 0",
        ),
        (
            {**GOOD, "tracker": {**GOOD["tracker"], "orientation_sigma_deg": 0}},
            "orientation_sigma_deg",
            "degrees",
        ),
        (
            {**GOOD, "encoders": {"reading_sigma_mm": "0.002"}},
            "encoders.reading_sigma_mm",
            "'0.002'",
        ),
        ({**GOOD, "encoders": {"reading_sigma_mm": True}}, "encoders.reading_sigma_mm", "number"),
        ({**GOOD, "encoders": {}}, "encoders.reading_sigma_mm", "required"),
        ({"tracker": GOOD["tracker"]}, "field encoders", "required"),
        ([1, 2], "(top level)", "dictionary"),
    ],
    ids=["negative", "zero", "string", "bool", "missing", "no-encoders", "not-object"],
)
def test_validation_errors_name_file_and_field(
    tmp_path: Path, data: object, field: str, text: str
) -> None:
    path = write_json(tmp_path, data, "noise.json")
    with pytest.raises(InstrumentsError) as info:
        load_instruments(path)
    message = str(info.value)
    assert message.startswith(f"{path}: field ")
    assert field in message and text in message
    assert info.value.path == str(path)


def test_nan_rejected(tmp_path: Path) -> None:
    path = tmp_path / "nan.json"
    path.write_text(json.dumps(GOOD).replace("0.01", "NaN"), encoding="utf-8")
    with pytest.raises(InstrumentsError, match=r"tracker\.position_sigma_mm"):
        load_instruments(path)


def test_file_errors(tmp_path: Path) -> None:
    with pytest.raises(InstrumentsError, match="no such file"):
        load_instruments(tmp_path / "absent.json")
    bad = tmp_path / "bad.json"
    bad.write_text('{\n  "tracker": {,\n}', encoding="utf-8")
    with pytest.raises(InstrumentsError, match=r"bad\.json: line 2, column 15: not valid JSON"):
        load_instruments(bad)
    latin = tmp_path / "latin.json"
    latin.write_bytes(b'{"note": "caf\xe9"}')
    with pytest.raises(InstrumentsError, match="UTF-8"):
        load_instruments(latin)
    assert issubclass(InstrumentsError, ValueError)
