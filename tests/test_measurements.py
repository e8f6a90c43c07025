"""measurements.csv: lossless round trip, row validation and its error messages, subsets."""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hexcal.measurements import (
    CONSTRAINTS,
    REQUIRED_COLUMNS,
    MeasurementError,
    Measurements,
    measurements_to_csv_text,
    read_measurements,
    write_measurements,
)

EXAMPLE = Path(__file__).parents[1] / ".." / "shared" / "examples" / "left-hand"
HEADER = (*REQUIRED_COLUMNS, "temperature", "note")
GOOD = {
    "t": "1.5",
    "step": "leg1-direction",
    "leg": "1",
    "constraint": "direction",
    "x": "1.0",
    "y": "2.0",
    "z": "200.0",
    "qw": "1",
    "qx": "0",
    "qy": "0",
    "qz": "0",
    "rho1": "10",
    "rho2": "20",
    "rho3": "30",
    "rho4": "40",
    "rho5": "50",
    "rho6": "60",
    "temperature": "20.5",
    "note": "ok",
}


def row(pose_id: int | str, **changes: str) -> str:
    """One CSV line of a good row, with some fields replaced."""
    values = {"pose_id": str(pose_id), **GOOD, **changes}
    return ",".join(values[c] for c in HEADER)


def write_csv(tmp_path: Path, lines: list[str], name: str = "meas.csv") -> Path:
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def sample(n: int = 12, seed: int = 0, **kwargs: object) -> Measurements:
    rng = np.random.default_rng(seed)
    legs = np.repeat(np.arange(0, 7), 2)[:n]
    constraint = np.array([CONSTRAINTS[3] if k == 0 else CONSTRAINTS[k % 3] for k in legs])
    return Measurements.from_arrays(
        rng.normal(0.0, 30.0, (n, 3)) / 3.0,  # values with long decimal expansions
        Rotation.random(n, rng=rng),
        rng.uniform(0.0, 100.0, (n, 6)),
        leg=legs,
        constraint=constraint,
        **kwargs,
    )


# ---------------------------------------------------------------------------- round trip


def test_from_arrays_round_trip(tmp_path: Path) -> None:
    m = sample(
        temperature=np.linspace(19.0, 21.0, 12) / 7.0,
        t=np.cumsum(np.full(12, 0.1)),
        extra={"operator": ["ann, b"] * 6 + ['say "hi"'] * 6, "gauge": 1.0 / 3.0},
    )
    path = tmp_path / "m.csv"
    write_measurements(m, path)
    back = read_measurements(path)
    assert back == m
    assert back.columns == (*REQUIRED_COLUMNS, "temperature", "operator", "gauge")
    assert back.source == str(path)
    assert np.array_equal(back.position, m.position)  # exact, not approximate
    assert back.extra["operator"][0] == "ann, b" and back.extra["operator"][-1] == 'say "hi"'
    assert back.extra["gauge"][0] == repr(1.0 / 3.0)
    assert back.position.dtype == float and back.pose_id.dtype == np.int64
    assert back.step.dtype == object and back.constraint.dtype == object


def test_from_arrays_defaults() -> None:
    q = np.tile([1.0, 0.0, 0.0, 0.0], (3, 1))
    m = Measurements.from_arrays(np.zeros((3, 3)), q, np.zeros((3, 6)))
    assert m.pose_id.tolist() == [1, 2, 3]
    assert m.t.tolist() == [0.0, 1.0, 2.0]
    assert m.leg.tolist() == [0, 0, 0]
    assert m.constraint.tolist() == ["free"] * 3 and m.step.tolist() == ["free"] * 3
    assert m.temperature is None and m.extra == {}
    assert m.columns == REQUIRED_COLUMNS and len(m) == 3
    clamped = Measurements.from_arrays(
        np.zeros((2, 3)), q[:2], np.zeros((2, 6)), leg=4, constraint="length"
    )
    assert clamped.step.tolist() == ["leg4-length"] * 2


def test_from_arrays_quaternion_kept_and_rotations_normalised() -> None:
    q = np.array([[1.0005, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    m = Measurements.from_arrays(np.zeros((2, 3)), q, np.zeros((2, 6)))
    assert np.array_equal(m.quaternion, q)  # not renormalised
    assert np.allclose(m.rotations.as_matrix()[1], np.diag([-1.0, -1.0, 1.0]))
    r = Rotation.from_euler("xyz", [[10, 20, 30], [0, 0, 5]], degrees=True)
    m2 = Measurements.from_arrays(np.zeros((2, 3)), r, np.zeros((2, 6)))
    assert np.allclose(m2.rotations.as_matrix(), r.as_matrix())


@pytest.mark.parametrize(
    ("kwargs", "column"),
    [
        ({"quaternion": [[1.1, 0, 0, 0]]}, "qw"),
        ({"leg": 7, "constraint": "length"}, "leg"),
        ({"constraint": "twist"}, "constraint"),
        ({"leg": 2}, "constraint"),  # clamped leg, but constraint defaults to free
        ({"constraint": "direction"}, "constraint"),  # clamped constraint on leg 0
        ({"t": [np.nan]}, "t"),
        ({"readings": [[1, 2, 3, 4, 5, np.inf]]}, "rho6"),
    ],
)
def test_from_arrays_rejects_bad_values(kwargs: dict, column: str) -> None:
    args = {"position": [[0.0, 0.0, 0.0]], "quaternion": [[1.0, 0, 0, 0]], "readings": [[0.0] * 6]}
    args.update(kwargs)
    with pytest.raises(MeasurementError) as info:
        Measurements.from_arrays(
            args.pop("position"), args.pop("quaternion"), args.pop("readings"), **args
        )
    assert info.value.column == column and f"'{column}'" in str(info.value)


def test_from_arrays_rejects_duplicate_ids_and_bad_shapes() -> None:
    q = np.tile([1.0, 0.0, 0.0, 0.0], (2, 1))
    with pytest.raises(MeasurementError, match="pose_id 5"):
        Measurements.from_arrays(np.zeros((2, 3)), q, np.zeros((2, 6)), pose_id=[5, 5])
    with pytest.raises(ValueError, match=r"readings must have shape \(2, 6\)"):
        Measurements.from_arrays(np.zeros((2, 3)), q, np.zeros((2, 5)))
    with pytest.raises(ValueError, match="clashes"):
        Measurements.from_arrays(np.zeros((2, 3)), q, np.zeros((2, 6)), extra={"x": [1, 2]})


def test_example_round_trip(tmp_path: Path) -> None:
    src = EXAMPLE / "measurements.csv"
    if not src.is_file():
        pytest.skip(f"shared example not present at {EXAMPLE}")
    m = read_measurements(src)
    with src.open(newline="", encoding="utf-8") as fh:
        table = list(csv.reader(fh))
    assert m.columns == tuple(table[0])
    assert len(m) == len(table) - 1
    # Independent parse of the same file: every value identical.
    cols = {name: [r[k] for r in table[1:]] for k, name in enumerate(table[0])}
    assert m.pose_id.tolist() == [int(v) for v in cols["pose_id"]]
    assert m.position[:, 2].tolist() == [float(v) for v in cols["z"]]
    assert m.quaternion[:, 0].tolist() == [float(v) for v in cols["qw"]]
    assert m.readings[:, 5].tolist() == [float(v) for v in cols["rho6"]]
    assert m.constraint.tolist() == cols["constraint"]
    out = tmp_path / "measurements.csv"
    write_measurements(m, out)
    back = read_measurements(out)
    assert back == m and back.columns == m.columns


def test_tolerates_crlf_blank_lines_whitespace_bom_and_quotes(tmp_path: Path) -> None:
    lines = [
        " , ".join(HEADER),
        row(1, step='"leg1, first"'),
        "",
        row(" 2 ", x=" 3.25 ", note='"a ""quoted"" note"'),
        ",,,,",  # the empty rows spreadsheets append
        row("3.0"),  # integers exported as floats
    ]
    path = tmp_path / "m.csv"
    path.write_bytes(b"\xef\xbb\xbf" + "\r\n".join(lines).encode() + b"\r\n")
    m = read_measurements(path)
    assert m.pose_id.tolist() == [1, 2, 3]
    assert m.step[0] == "leg1, first" and m.extra["note"][1] == 'a "quoted" note'
    assert m.position[1, 0] == 3.25
    assert m.columns == HEADER


def test_extra_columns_kept_as_text(tmp_path: Path) -> None:
    header = ",".join(HEADER) + ",serial,flag"
    path = write_csv(tmp_path, [header, row(1) + ",007,", row(2) + ",1.50,yes"])
    m = read_measurements(path)
    assert list(m.extra) == ["note", "serial", "flag"]
    assert m.extra["serial"].tolist() == ["007", "1.50"]  # not turned into numbers
    assert m.extra["flag"].tolist() == ["", "yes"]
    text = measurements_to_csv_text(m)
    assert text.splitlines()[0] == header
    assert text.splitlines()[1].endswith(",ok,007,")


def test_temperature_absent_stays_absent(tmp_path: Path) -> None:
    header = [c for c in HEADER if c != "temperature"]
    lines = [",".join(header), ",".join({"pose_id": "1", **GOOD}[c] for c in header)]
    m = read_measurements(write_csv(tmp_path, lines))
    assert m.temperature is None
    assert "temperature" not in measurements_to_csv_text(m).splitlines()[0]


# ---------------------------------------------------------------------------- errors

ROW_ERRORS = [
    # (id, data rows, bad line, column, text in message)
    ("non-numeric", [row(1), row(2, qw="abc")], 3, "qw", "'abc' is not a number"),
    ("empty", [row(1, y="")], 2, "y", "empty"),
    ("empty-step", [row(1, step="")], 2, "step", "empty"),
    ("empty-temperature", [row(1, temperature="")], 2, "temperature", "empty"),
    ("nan", [row(1), row(2), row(3, z="NaN")], 4, "z", "not a finite number"),
    ("inf", [row(1, rho3="-inf")], 2, "rho3", "not a finite number"),
    ("overflow", [row(1, t="1e999")], 2, "t", "not a finite number"),
    ("quaternion", [row(1, qw="0.9")], 2, "qw", "norm 0.900000"),
    ("constraint", [row(1, constraint="twist")], 2, "constraint", "direction+length"),
    ("leg-range", [row(1, leg="7")], 2, "leg", "outside 0..6"),
    ("leg-negative", [row(1, leg="-1")], 2, "leg", "outside 0..6"),
    ("leg0-clamped", [row(1, leg="0")], 2, "constraint", "leg is 0"),
    ("free-clamped", [row(1, constraint="free")], 2, "constraint", "leg is 1"),
    ("pose-id-float", [row("1.5")], 2, "pose_id", "not an integer"),
    ("pose-id-text", [row("a")], 2, "pose_id", "not an integer"),
    ("duplicate-id", [row(1), row(2), row(1)], 4, "pose_id", "already used on line 2"),
    ("too-few", [row(1), "2,1.5,s,1"], 3, "constraint", "4 fields"),
    ("too-many", [row(1) + ",extra"], 2, "note", "21 fields"),
]


@pytest.mark.parametrize(
    ("rows", "line", "column", "text"),
    [case[1:] for case in ROW_ERRORS],
    ids=[case[0] for case in ROW_ERRORS],
)
def test_row_errors(tmp_path: Path, rows: list[str], line: int, column: str, text: str) -> None:
    path = write_csv(tmp_path, [",".join(HEADER), *rows], name="bad-table.csv")
    with pytest.raises(MeasurementError) as info:
        read_measurements(path)
    err = info.value
    message = str(err)
    assert "bad-table.csv" in message
    assert f"line {line}," in message or f"line {line}:" in message
    assert f"'{column}'" in message
    assert text in message
    assert err.line == line and err.path == str(path)


HEADER_ERRORS = [
    ("missing", [c for c in HEADER if c != "qx"], "qx", "missing"),
    ("case", [c.upper() if c == "rho4" else c for c in HEADER], "rho4", "lower case"),
    ("duplicate", [*HEADER, "x"], "x", "appears twice"),
    ("unnamed", [*HEADER, ""], "column 21", "has no name"),
]


@pytest.mark.parametrize(
    ("header", "column", "text"),
    [case[1:] for case in HEADER_ERRORS],
    ids=[case[0] for case in HEADER_ERRORS],
)
def test_header_errors(tmp_path: Path, header: list[str], column: str, text: str) -> None:
    path = write_csv(tmp_path, [",".join(header), row(1)], name="hdr.csv")
    with pytest.raises(MeasurementError) as info:
        read_measurements(path)
    message = str(info.value)
    assert message.startswith(f"{path}: line 1")
    assert column in message and text in message


@pytest.mark.parametrize(
    ("content", "line", "text"),
    [
        (b"", 1, "empty"),
        (b"\n  \n", 1, "empty"),
        (",".join(HEADER).encode() + b"\r\n", 2, "no data rows"),
    ],
    ids=["empty", "blank", "header-only"],
)
def test_empty_files(tmp_path: Path, content: bytes, line: int, text: str) -> None:
    path = tmp_path / "empty.csv"
    path.write_bytes(content)
    with pytest.raises(MeasurementError) as info:
        read_measurements(path)
    assert info.value.line == line
    assert str(info.value).startswith(f"{path}: line {line}:") and text in str(info.value)


def test_not_utf8_names_line_and_column(tmp_path: Path) -> None:
    path = tmp_path / "latin.csv"
    text = "\n".join([",".join(HEADER), row(1), row(2, note="caf\xe9")]) + "\n"
    path.write_bytes(text.encode("latin-1"))
    with pytest.raises(MeasurementError) as info:
        read_measurements(path)
    assert (info.value.line, info.value.column) == (3, "note")
    assert "latin.csv: line 3, column 'note'" in str(info.value) and "UTF-8" in str(info.value)


def test_missing_file_and_directory(tmp_path: Path) -> None:
    with pytest.raises(MeasurementError, match="no such file") as info:
        read_measurements(tmp_path / "absent.csv")
    assert "absent.csv" in str(info.value) and info.value.__cause__ is None
    with pytest.raises(MeasurementError, match="directory"):
        read_measurements(tmp_path)


def test_all_bad_rows_reported_together(tmp_path: Path) -> None:
    rows = [row(1, qw="x"), row(2), row(3, leg="9", rho1=""), row(4, constraint="Length")]
    path = write_csv(tmp_path, [",".join(HEADER), *rows])
    with pytest.raises(MeasurementError) as info:
        read_measurements(path)
    found = [(i.line, i.column) for i in info.value.issues]
    assert found == [(2, "qw"), (4, "leg"), (4, "rho1"), (5, "constraint")]
    assert "lower case" in str(info.value)
    assert len(str(info.value).splitlines()) == 4


def test_error_count_is_capped(tmp_path: Path) -> None:
    rows = [row(k, x="?") for k in range(1, 31)]
    with pytest.raises(MeasurementError) as info:
        read_measurements(write_csv(tmp_path, [",".join(HEADER), *rows]))
    lines = str(info.value).splitlines()
    assert len(info.value.issues) == 20 and len(lines) == 21
    assert "10 more" in lines[-1] and "line 21," in lines[-2]


# ---------------------------------------------------------------------------- writing


def test_write_is_atomic_and_leaves_no_temp_file(tmp_path: Path) -> None:
    path = tmp_path / "m.csv"
    path.write_text("old\n", encoding="utf-8")
    m = sample()
    write_measurements(m, path)
    assert os.listdir(tmp_path) == ["m.csv"]
    assert read_measurements(path) == m


def test_failed_write_keeps_old_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "m.csv"
    path.write_text("old\n", encoding="utf-8")

    def fail(*args: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError, match="disk full"):
        write_measurements(sample(), path)
    assert os.listdir(tmp_path) == ["m.csv"]
    assert path.read_text(encoding="utf-8") == "old\n"


def test_write_refuses_unreadable_tables(tmp_path: Path) -> None:
    m = sample()
    with pytest.raises(ValueError, match="no poses"):
        write_measurements(m.subset(m.leg == 99), tmp_path / "a.csv")
    with pytest.raises(MeasurementError, match="pose_id 1"):
        write_measurements(m.subset([0, 0]), tmp_path / "b.csv")
    assert os.listdir(tmp_path) == []


# ---------------------------------------------------------------------------- subsets


def test_subset_and_select(tmp_path: Path) -> None:
    m = sample(temperature=20.0, extra={"tag": [f"p{k}" for k in range(12)]})
    m = read_measurements(write_csv(tmp_path, measurements_to_csv_text(m).splitlines()))
    s = m.select(3, "direction")
    assert s.pose_id.tolist() == [7, 8]
    assert s.extra["tag"].tolist() == ["p6", "p7"] and s.temperature.tolist() == [20.0, 20.0]
    assert s.columns == m.columns and s.source == m.source
    assert np.array_equal(s.quaternion, m.quaternion[6:8])
    assert len(m.select(0, "free")) == 2 and len(m.select(1, "length")) == 0
    assert (
        m.subset(slice(2, 5))
        == m.subset([2, 3, 4])
        == m.subset((np.arange(12) >= 2) & (np.arange(12) < 5))
    )
    one = m.subset(4)
    assert len(one) == 1 and one.readings.shape == (1, 6) and one.position.shape == (1, 3)
    boot = m.subset([1, 1, 2])  # resampling with repeats is allowed in memory
    assert boot.pose_id.tolist() == [2, 2, 3]
    assert m.subset(np.ones(12, dtype=bool)) == m
    with pytest.raises(ValueError, match="unknown constraint"):
        m.select(1, "Type I")
    with pytest.raises(IndexError):
        m.subset(np.ones(3, dtype=bool))


def test_equality_is_exact() -> None:
    m = sample()
    nudged = m.position.copy()
    nudged[0, 0] = np.nextafter(nudged[0, 0], np.inf)
    other = Measurements.from_arrays(
        nudged, m.quaternion, m.readings, leg=m.leg, constraint=m.constraint
    )
    assert other != m
    assert (
        Measurements.from_arrays(
            m.position, m.quaternion, m.readings, leg=m.leg, constraint=m.constraint
        )
        == m
    )
