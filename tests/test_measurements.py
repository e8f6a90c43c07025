"""measurements.csv: lossless round trip, row validation and its error messages, subsets."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
import textwrap
from pathlib import Path
from unittest import mock

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from hexcal.io.measurements import (
    CONSTRAINTS,
    REQUIRED_COLUMNS,
    MeasurementError,
    Measurements,
    measurements_to_csv_text,
    write_measurements,
)
from hexcal.io.measurements_csv import read_measurements

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


def test_from_arrays_bounds_pose_ids_and_speaks_plain_numbers() -> None:
    """An id beyond int64 is refused, not wrapped to -9223372036854775808; messages show a
    number as a file would, never numpy's repr."""
    args = (np.zeros((1, 3)), [[1.0, 0, 0, 0]], np.zeros((1, 6)))
    with pytest.raises(ValueError, match=r"pose_id must hold integers within ±2\*\*63"):
        Measurements.from_arrays(*args, pose_id=[10**30])
    with pytest.raises(MeasurementError, match=r"outside 1\.\.9007199254740991"):
        Measurements.from_arrays(*args, pose_id=np.array([2**60]))
    with pytest.raises(MeasurementError) as info:
        Measurements.from_arrays(*args, t=[np.float64("nan")])
    assert "'t': nan is not finite" in str(info.value) and "np." not in str(info.value)


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
    ("pose-id-zero", [row(0)], 2, "pose_id", "outside 1..9007199254740991"),
    ("pose-id-2**53", [row(2**53)], 2, "pose_id", "outside 1..9007199254740991"),
    ("pose-id-1e30", [row("1" + "0" * 30)], 2, "pose_id", "outside 1..9007199254740991"),
    ("coordinate-1e300", [row(1, x="1e300")], 2, "x", "1e+300 mm is outside -1e+06..1e+06 mm"),
    ("reading-huge", [row(1, rho2="-2e6")], 2, "rho2", "outside -1e+06..1e+06 mm"),
    ("time-huge", [row(1, t="1e10")], 2, "t", "outside -1e+09..1e+09 s"),
    ("below-absolute-zero", [row(1, temperature="-300")], 2, "temperature", "outside -273.15"),
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


def test_problems_in_later_blocks_are_found_in_line_order(tmp_path: Path) -> None:
    """The reader checks blocks of rows at a time: a bad row and a repeated id far from the
    first block are reported with their lines, in line order, across blocks."""
    rows = [row(k) for k in range(1, 10_001)]
    rows[8999] = row(9000, qw="0.5")  # line 9001
    rows[4999] = row(1)  # line 5001 repeats line 2's id
    rows[9999] = row(10_000, constraint="Twist")  # line 10001
    with pytest.raises(MeasurementError) as info:
        read_measurements(write_csv(tmp_path, [",".join(HEADER), *rows]))
    found = [(i.line, i.column) for i in info.value.issues]
    assert found == [(5001, "pose_id"), (9001, "qw"), (10001, "constraint")]
    assert "already used on line 2" in str(info.value)


def test_a_valid_table_across_blocks_reads_exactly(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    n = 9000
    legs = np.arange(n) % 7
    m = Measurements.from_arrays(
        rng.normal(0.0, 30.0, (n, 3)) / 3.0,
        Rotation.random(n, rng=rng),
        rng.uniform(0.0, 100.0, (n, 6)),
        leg=legs,
        constraint=np.array([CONSTRAINTS[3] if k == 0 else CONSTRAINTS[k % 3] for k in legs]),
        temperature=20.25,
        extra={"tag": [f"p{k}" for k in range(n)]},
    )
    path = tmp_path / "m.csv"
    write_measurements(m, path)
    assert read_measurements(path) == m


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


# ---------------------------------------------------------------------------- the block check

# Values near every rule's edge, and the spellings float() and int() take but the rules refuse.
EDGE_VALUES = [
    "0",
    "-0",
    "+5",
    "3.0",
    "3.",
    "7",
    "-1",
    " 1 ",
    "\t2",
    "\x1c3\x1f",
    "",
    " ",
    "1_0",
    "١",
    "1e6",
    "1000000.0000001",
    "-1e6",
    "1e9",
    "1e9000",
    "nan",
    "-inf",
    "9007199254740991",
    "9007199254740992",
    "9223372036854775808",
    "0.999",
    "1.001",
    "1.0009999999",
    "0.9990000001",
    "-273.15",
    "-273.16",
    "1000",
    "free",
    " free ",
    "length",
    "Length",
    "direction+length",
    "x",
    "leg1_direction",
    "Bein ü",
]


@pytest.fixture(scope="module")
def block_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("blocks")


@pytest.mark.fuzz
@given(data=st.data())
def test_the_block_check_agrees_with_the_row_check(block_dir: Path, data: st.DataObject) -> None:
    """Whatever the values, reading a block at a time with numpy gives exactly what
    validating every row with MeasurementRow gives: the same table, or the same error."""
    from hexcal.io.measurements_csv import _Slow, _TableReader

    n = data.draw(st.integers(1, 6), label="rows")
    rows = [{"pose_id": str(k + 1), **GOOD} for k in range(n)]
    for _ in range(data.draw(st.integers(0, 4), label="changes")):
        r = data.draw(st.integers(0, n - 1))
        column = data.draw(st.sampled_from(HEADER))
        rows[r][column] = data.draw(st.sampled_from(EDGE_VALUES))
    path = block_dir / "m.csv"
    path.write_text(
        "\n".join([",".join(HEADER)] + [",".join(r[c] for c in HEADER) for r in rows]) + "\n",
        encoding="utf-8",
    )

    def outcome() -> object:
        try:
            return read_measurements(path)
        except MeasurementError as exc:
            return str(exc)

    fast = outcome()

    def slow(self: object, rows: object) -> None:
        raise _Slow

    with mock.patch.object(_TableReader, "_fast", slow):
        by_rows = outcome()
    assert fast == by_rows


@pytest.mark.slow
def test_a_200_mb_table_reads_in_under_1_gb(tmp_path: Path) -> None:
    """Memory stays about the file's size: a ~200 MB measurements.csv, read in a fresh
    process, peaks well under 1 GB (the reader before streaming took 6.7 GB)."""
    example = Path(__file__).parents[1] / "examples" / "left-hand-sim" / "measurements.csv"
    header, *rows = example.read_text(encoding="utf-8").splitlines()
    body = [r.split(",", 1)[1] for r in rows]
    path = tmp_path / "big.csv"
    size, k = 0, 0
    with path.open("w", encoding="utf-8") as fh:
        fh.write(header + "\n")
        while size < 200_000_000:
            chunk = "".join(f"{k + i + 1},{body[(k + i) % len(body)]}\n" for i in range(10_000))
            fh.write(chunk)
            size, k = size + len(chunk), k + 10_000
    code = textwrap.dedent(
        """
        import resource, sys, time
        from hexcal.io.measurements_csv import read_measurements
        start = time.perf_counter()
        m = read_measurements(sys.argv[1])
        took = time.perf_counter() - start
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # KiB on Linux
        print(len(m), peak, took)
        """
    )
    out = subprocess.run(
        [sys.executable, "-c", code, str(path)], capture_output=True, text=True, check=True
    )
    rows, peak, took = out.stdout.split()
    assert int(rows) == k
    assert int(peak) < 1_000_000_000, f"peak RSS {int(peak) / 1e6:.0f} MB, read in {took} s"


@pytest.mark.parametrize("block", [3, 1 << 22])
def test_line_ends_bound_the_rows_and_count_rows_counts_them_exactly(tmp_path, monkeypatch, block):
    """The line ends (\\n, \\r\\n, a lone \\r; a \\r\\n split between two blocks once) are at
    least the rows the reader finds; the exact count leaves out blank and all-comma rows and
    the header, and counts a row whose quoted cell breaks across lines once, in every dialect
    the reader takes (Excel's sep= line, UTF-16)."""
    import hexcal.io.measurements_csv as measurements_csv
    from hexcal.io.measurements_csv import count_rows, line_ends

    monkeypatch.setattr(measurements_csv, "_COUNT_BLOCK", block)
    src = Path(__file__).resolve().parents[1] / "examples" / "left-hand-sim" / "measurements.csv"
    lines = src.read_text().splitlines()[:6]  # the header and 5 rows
    cases = {
        "lf.csv": ("\n".join(lines) + "\n").encode(),
        "crlf.csv": ("\r\n".join(lines) + "\r\n").encode(),
        "cr.csv": ("\r".join(lines)).encode(),
        "blank.csv": ("\n\n".join(lines) + "\n,,,,\n\n").encode(),
        "sep.csv": ("sep=;\r\n" + "\r\n".join(x.replace(",", ";") for x in lines)).encode(),
        "utf16.csv": ("\ufeff" + "\r\n".join(lines) + "\r\n").encode("utf-16-le"),
    }
    quoted = [lines[0] + ",note"] + [
        x + (',"two\nlines"' if i == 2 else ",") for i, x in enumerate(lines[1:], 1)
    ]
    cases["quoted.csv"] = "\n".join(quoted).encode()
    for name, data in cases.items():
        path = tmp_path / name
        path.write_bytes(data)
        assert count_rows(path) == 5 == len(read_measurements(path)), name
        assert line_ends(path) >= 5, name
    assert line_ends(tmp_path / "crlf.csv") == 6 and line_ends(tmp_path / "cr.csv") == 5
    assert line_ends(tmp_path / "blank.csv") == 13 and line_ends(tmp_path / "quoted.csv") == 6
