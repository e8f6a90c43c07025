"""Regression corpus: the nested, huge, non-finite and undecodable inputs a fuzzing campaign
found, as small files in tests/data/bad_inputs/ (the large ones are generated here). Each is
refused by its reader's own error with a message that names the file and the field or line and
says what to do. How long each refusal takes (milliseconds; a quadratic or runaway parse would
show) is measured by benchmarks/bad_input_refusal.py, not asserted here."""

from __future__ import annotations

from pathlib import Path

import pytest

from hexcal.acquire.devices import DevicesConfigError, load_devices_config
from hexcal.estimate.model_file import load_model, load_robot
from hexcal.estimate.predict_table import TableError, read_table
from hexcal.io.measurements import MeasurementError
from hexcal.io.measurements_csv import read_measurements
from hexcal.model.instruments import InstrumentsError, load_instruments
from hexcal.model.robot import RobotFileError
from hexcal.procedure.session import SessionFileError, load_session
from hexcal.procedure.steps import ProcedureError, load_procedure

BAD = Path(__file__).parent / "data" / "bad_inputs"


def read_predict_table(path: Path) -> None:
    """What hexcal predict does before the model: read the table and every column's values."""
    table = read_table(path)
    for name in table.header:
        table.column(name)


READERS = {
    "robot": (load_robot, RobotFileError),
    "calibrated": (load_model, RobotFileError),
    "instruments": (load_instruments, InstrumentsError),
    "session": (load_session, SessionFileError),
    "procedure": (load_procedure, ProcedureError),
    "devices": (load_devices_config, DevicesConfigError),
    "measurements": (read_measurements, MeasurementError),
    "table": (read_predict_table, TableError),
}

# file -> texts the message must hold (the field or the line, and what is wrong)
CASES = {
    # keys given twice, true for a number, a repeated pose id, files as spreadsheets save them
    "robot-duplicate-key.json": ["line 69", "key 'leg_offsets' is given twice (first on line 68)"],
    "instruments-duplicate-key.json": ["key 'position_sigma_mm' (in field tracker) is given twice"],
    "session-duplicate-key.json": ["line 191", "key 'notes' is given twice"],
    "devices-duplicate-table.toml": ["line 8", "table '[tracker]' is given twice"],
    "procedure-duplicate-key.toml": ["line 12", "key 'min_poses' is given twice"],
    "robot-bool-coordinate.json": ["field base_points.0.1", "not a boolean"],
    "session-bool-coordinate.json": ["field poses.0.position.1", "not a boolean", "left untouched"],
    "session-duplicate-column.json": ["field columns.19", "column 'rho1' appears twice"],
    "session-repeated-pose-id.json": [
        "pose 1 (field poses.1.pose_id)",
        "the id repeats poses.0's",
        "left untouched",
    ],
    "measurements-cp1252.csv": ["line 2, column 'step'", "not UTF-8", "Windows-1252", "CSV UTF-8"],
    "measurements-decimal-commas.csv": ["line 2", "decimal commas", "';' as the separator"],
    "table-decimal-commas.csv": ["line 2", "decimal commas", "';' as the separator"],
    "robot-nan.json": ["field base_points.0.1", "NaN is not a finite number"],
    "robot-infinity.json": ["field leg_offsets.2", "Infinity is not a finite number"],
    "robot-overflow.json": ["field home.position.2", "Infinity is not a finite number"],
    "robot-1e300.json": ["field platform_points.3.0", "less than or equal to 1000000", "1e+300"],
    "robot-mass-zero.json": ["field platform_mass_kg", "greater than 0", "(got 0)"],
    "robot-bigint.json": ["more than 4300 digits"],
    "robot-deep.json": ["nested more than 32 levels", "field vendor.a.a"],
    "robot-deep-arrays.json": ["nested more than 32 levels"],
    "robot-not-utf8.json": ["byte 15 (line 2, 0x96) is not UTF-8 text", "save the file as UTF-8"],
    "calibrated-sigma-infinity.json": ["field calibration.effects.0.parameters.0.sigma"],
    "calibrated-rms-negative.json": ["field calibration.fit.rms_mm", "greater than or equal to 0"],
    "calibrated-format-version-huge.json": ["upgrade hexcal"],
    "calibrated-deep.json": ["nested more than 32 levels", "calibration.fit.clamps"],
    "instruments-sigma-1e300.json": ["field tracker.position_sigma_mm", "1e+300", "≤ 1000"],
    "instruments-nan.json": ["field encoders.reading_sigma_mm", "NaN"],
    "instruments-deep.json": ["nested more than 32 levels", "field note.a"],
    "session-pose-id-huge.json": ["field poses.0.pose_id", "9007199254740991", "left untouched"],
    "session-result-pose-id-huge.json": ["field results.0.pose_ids.1", "9223372036854775808"],
    "session-nan.json": ["field poses.1.readings.3", "NaN is not a finite number"],
    "session-infinity-t.json": ["field poses.1.t", "Infinity is not a finite number"],
    "session-deep.json": ["nested more than 32 levels", "field procedure.a"],
    "procedure-dotted-key.toml": ["line 11", "dotted key has more than 32 parts"],
    "procedure-deep-tables.toml": ["line 11", "dotted key has more than 32 parts"],
    "procedure-nested-arrays.toml": ["line 11", "nested more than 32 levels"],
    "procedure-nan.toml": ["field steps.0.tolerance_mm", "NaN is not a finite number"],
    "procedure-overflow.toml": ["field steps.0.target_sigma_mm", "Infinity"],
    "procedure-huge-poses.toml": ["step 1 (id 'free'), field min_poses", "10000"],
    "devices-timeout-inf.toml": ["field tracker.timeout_s", "Infinity is not a finite number"],
    "devices-timeout-huge.toml": ["field tracker.timeout_s", "less than or equal to 60"],
    "devices-baudrate-huge.toml": ["field tracker.baudrate", "99999999999999999999"],
    "devices-still-nan.toml": ["field still.duration_s", "NaN"],
    "devices-counts-huge.toml": ["field can", "counts_per_mm", "1e+300"],
    "devices-deep-inline.toml": ["line 3", "nested more than 32 levels"],
    "devices-utf16.toml": ["byte 0 (line 1, 0xff) is not UTF-8 text"],
    "measurements-pose-id-huge.csv": ["line 2, column 'pose_id'", "outside 1..9007199254740991"],
    "measurements-pose-id-2-63.csv": ["line 3, column 'pose_id'", "9223372036854775808"],
    "measurements-1e300.csv": ["line 3, column 'x'", "1e+300 mm is outside"],
    "measurements-nan.csv": ["line 3, column 'rho2'", "not a finite number"],
    "measurements-temperature-overflow.csv": ["line 3, column 'temperature'", "'1e400'"],
    "measurements-not-utf8.csv": ["line 4, column 'step'", "(0x96) is not UTF-8 text"],
    "table-nan.csv": ["line 2, column 'rho3'", "not a finite number"],
    "table-1e300.csv": ["line 2, column 'z'", "outside"],
    "table-not-utf8.csv": ["line 2", "is not UTF-8 text"],
}


def _refused(path: Path, kind: str) -> str:
    read, error = READERS[kind]
    with pytest.raises(error) as info:
        read(path)
    message = str(info.value)
    assert str(path) in message, message
    assert "errors.pydantic.dev" not in message and "np.float64" not in message, message
    return message


def test_the_corpus_is_covered() -> None:
    assert sorted(p.name for p in BAD.iterdir()) == sorted(CASES)


@pytest.mark.parametrize("name", sorted(CASES))
def test_a_bad_input_is_refused_naming_file_and_field(name: str) -> None:
    message = _refused(BAD / name, name.split("-")[0])
    for text in CASES[name]:
        assert text in message, f"{text!r} not in {message!r}"


# -- Large inputs, generated (not committed) --------------------------------------------------


def test_an_oversized_file_is_refused_before_it_is_read(tmp_path: Path) -> None:
    path = tmp_path / "robot.json"
    path.write_bytes(b" " * (2 * 1024 * 1024) + b"{}")
    assert "2 MB, more than the 1 MB a robot description may have" in _refused(path, "robot")


def test_a_device_that_never_ends_is_cut_at_the_limit() -> None:
    if not Path("/dev/zero").exists():
        pytest.skip("no /dev/zero")
    message = _refused(Path("/dev/zero"), "instruments")
    assert "longer than 1 MB" in message


def test_a_100000_part_dotted_key_is_refused_before_tomllib(tmp_path: Path) -> None:
    """200 KB that grew tomllib to 23 GB (quadratic in the key's parts)."""
    path = tmp_path / "lab.toml"
    path.write_text("name = 'x'\nmodel = 42\n" + "a." * 100_000 + "a = 1\n")
    assert "line 3: a dotted key has more than 32 parts" in _refused(path, "procedure")


def test_deep_json_and_toml_are_refused(tmp_path: Path) -> None:
    deep_json = tmp_path / "s.json"
    deep_json.write_text('{"schema_version": 2, "x": ' + "[" * 100_000 + "]" * 100_000 + "}")
    assert "nested more than 32 levels" in _refused(deep_json, "session")
    deep_toml = tmp_path / "rig.toml"
    deep_toml.write_text("x = " + "{a = " * 100_000 + "1" + "}" * 100_000 + "\n")
    assert "line 1: nested more than 32 levels" in _refused(deep_toml, "devices")


def test_a_csv_field_beyond_the_csv_limit(tmp_path: Path) -> None:
    path = tmp_path / "m.csv"
    header = "pose_id,t,step,leg,constraint,x,y,z,qw,qx,qy,qz,rho1,rho2,rho3,rho4,rho5,rho6"
    path.write_text(f"{header}\n1,0,{'s' * 200_000},0,free,0,0,0,1,0,0,0,1,1,1,1,1,1\n")
    assert "line 2: not valid CSV (field larger than field limit" in _refused(path, "measurements")
    assert "line 2: not valid CSV" in _refused(path, "table")


# -- through the command line, as a user meets them -------------------------------------------
EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "left-hand-sim"


def _cli_args(name: str, path: Path) -> list[str]:
    """The hexcal command that reads ``path`` in the role its name says."""
    robot, meas, inst = (
        EXAMPLE / n for n in ("robot.json", "measurements.csv", "instruments.json")
    )
    kind = name.split("-", 1)[0]
    if kind in ("robot", "calibrated"):
        return ["calibrate", str(meas), "--robot", str(path)]
    if kind == "instruments":
        return ["calibrate", str(meas), "--robot", str(robot), "--instruments", str(path)]
    if kind == "measurements":
        return ["calibrate", str(path), "--robot", str(robot), "--instruments", str(inst)]
    if kind == "session":
        return ["calibrate", str(path)]
    if kind == "table":
        return ["predict", str(robot), str(path)]
    if kind == "procedure":
        return ["demo", "--procedure", str(path), "--poses-per-step", "3"]
    return ["devices", "check", "--config", str(path)]


@pytest.mark.parametrize("name", sorted(p.name for p in BAD.iterdir()))
def test_the_command_line_refuses_each_bad_input_cleanly(name: str, capsys) -> None:
    """Each corpus file through the command that reads it (``main``, the console script's entry
    point, which owns the one error path): exit 2, the file named, no traceback and no library
    text."""
    from hexcal.app.cli import main

    assert main(_cli_args(name, BAD / name)) == 2
    err = capsys.readouterr().err
    assert name in err
    for raw in ("Traceback", "errors.pydantic.dev", "np.float64", "codec can't decode"):
        assert raw not in err
