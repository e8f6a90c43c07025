"""Files as labs write them: the example table saved as spreadsheets and lab software save it —
semicolons and decimal commas (a European locale), tabs, a byte-order mark, CRLF, quoted
headers and cells, Excel's ``sep=`` line, Excel's UTF-16 "Unicode text", padding columns — is
read to the same table, and said so; what cannot be read unambiguously (decimal commas in a
comma-separated file, Windows-1252 text, digit grouping) is refused naming the variant and the
fix. The same for hexcal predict's tables and hexcal import's logs."""

from __future__ import annotations

import codecs
import csv
import io
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from hexcal.app.cli import main
from hexcal.estimate.predict_table import TableError, read_table
from hexcal.io.log_import import LogImportError, import_log, load_map
from hexcal.io.measurements import MeasurementError
from hexcal.io.measurements_csv import read_measurements

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "left-hand-sim"
ROWS = list(csv.reader((EXAMPLE / "measurements.csv").open()))
NUMERIC = {i for i, name in enumerate(ROWS[0]) if name not in ("step", "constraint")}


def _text(rows: list[list[str]], sep: str = ",", end: str = "\n", quote_all: bool = False) -> str:
    buf = io.StringIO()
    quoting = csv.QUOTE_ALL if quote_all else csv.QUOTE_MINIMAL
    csv.writer(buf, delimiter=sep, lineterminator=end, quoting=quoting).writerows(rows)
    return buf.getvalue()


def _decimal_commas(rows: list[list[str]]) -> list[list[str]]:
    return [rows[0]] + [
        [c.replace(".", ",") if i in NUMERIC else c for i, c in enumerate(r)] for r in rows[1:]
    ]


#: variant -> the file's bytes, and what the notice names ("" for hexcal's own dialect)
READ: dict[str, tuple[Callable[[], bytes], str]] = {
    "semicolons, decimal commas (Excel, European locale)": (
        lambda: _text(_decimal_commas(ROWS), ";", "\r\n").encode(),
        "separated by semicolons, with decimal commas",
    ),
    "semicolons, decimal points": (lambda: _text(ROWS, ";").encode(), "separated by semicolons"),
    "tabs": (lambda: _text(ROWS, "\t").encode(), "separated by tabs"),
    "byte-order mark and CRLF": (lambda: codecs.BOM_UTF8 + _text(ROWS, end="\r\n").encode(), ""),
    "CR line ends": (lambda: _text(ROWS, end="\r").encode(), ""),
    "quoted headers and cells": (lambda: _text(ROWS, quote_all=True).encode(), ""),
    "decimal commas quoted in a comma-separated file": (
        lambda: _text(_decimal_commas(ROWS), ",", quote_all=True).encode(),
        "separated by commas, with decimal commas",
    ),
    "Excel's sep= line": (
        lambda: ("sep=;\r\n" + _text(_decimal_commas(ROWS), ";", "\r\n")).encode(),
        "after Excel's 'sep=' line",
    ),
    "Excel's Unicode text (UTF-16, tabs)": (
        lambda: codecs.BOM_UTF16_LE + _text(ROWS, "\t", "\r\n").encode("utf-16-le"),
        "in UTF-16",
    ),
    "padding columns (a sheet formatted past its data)": (
        lambda: _text([[*r, "", ""] for r in ROWS], ";").encode(),
        "padded with 2 empty column(s)",
    ),
}

#: variant -> the file's bytes, and what the refusal names (the variant and the fix)
REFUSED: dict[str, tuple[Callable[[], bytes], list[str]]] = {
    "decimal commas in a comma-separated file": (
        lambda: _text(_decimal_commas(ROWS), ",").replace('"', "").encode(),
        ["decimal commas in a file separated by commas", "Save it again with ';'"],
    ),
    "Windows-1252 text": (
        lambda: _text([ROWS[0], [*ROWS[1][:2], "Bein-1-Länge", *ROWS[1][3:]], *ROWS[2:]]).encode(
            "cp1252"
        ),
        ["is not UTF-8 text", "Windows-1252", "choose 'CSV UTF-8'"],
    ),
    "digit grouping": (
        lambda: _text([ROWS[0], [*ROWS[1][:12], "1,086.621", *ROWS[1][13:]], *ROWS[2:]]).encode(),
        ["line 2, column 'rho1'", "'1,086.621' is not a number (digit grouping?"],
    ),
}


@pytest.fixture(scope="module")
def example():
    return read_measurements(EXAMPLE / "measurements.csv")


@pytest.mark.parametrize("variant", sorted(READ))
def test_a_variant_is_read_to_the_same_table_and_said(tmp_path, example, variant):
    content, said = READ[variant]
    path = tmp_path / "lab.csv"
    path.write_bytes(content())
    notices: list[str] = []
    table = read_measurements(path, notices)
    for name in ("pose_id", "t", "leg", "position", "quaternion", "readings", "temperature"):
        assert np.array_equal(getattr(table, name), getattr(example, name)), name
    assert list(table.step) == list(example.step)
    if said:
        assert notices == [f"{path}: read as a table {notices[0].split('as a table ')[1]}"]
        assert said in notices[0]
    else:
        assert notices == []


@pytest.mark.parametrize("variant", sorted(REFUSED))
def test_a_variant_that_cannot_be_read_is_refused_naming_it_and_the_fix(tmp_path, variant):
    content, expected = REFUSED[variant]
    path = tmp_path / "lab.csv"
    path.write_bytes(content())
    with pytest.raises(MeasurementError) as info:
        read_measurements(path)
    for text in expected:
        assert text in str(info.value), str(info.value)


def test_the_command_line_reads_a_european_spreadsheet_and_says_so(tmp_path, capsys):
    path = tmp_path / "lab.csv"
    path.write_bytes(READ["semicolons, decimal commas (Excel, European locale)"][0]())
    args = ["--robot", str(EXAMPLE / "robot.json"), "--instruments"]
    code = main(["calibrate", str(path), *args, str(EXAMPLE / "instruments.json"), "--no-refine"])
    assert code == 0
    assert "read as a table separated by semicolons, with decimal commas" in capsys.readouterr().err


def test_predict_reads_a_spreadsheets_table(tmp_path):
    path = tmp_path / "table.csv"
    path.write_bytes(_text(_decimal_commas(ROWS[:4]), ";").encode())
    table = read_table(path)
    assert table.decimal == ","
    assert np.array_equal(table.column("rho1"), [float(r[12]) for r in ROWS[1:4]])
    path.write_bytes(_text(_decimal_commas(ROWS[:4]), ",").replace('"', "").encode())
    with pytest.raises(TableError, match="decimal commas in a file separated by commas"):
        read_table(path)


def test_import_reads_a_log_saved_with_semicolons_and_decimal_commas(tmp_path):
    log = ROOT / "examples" / "jugglebot" / "108_calibration_poses.csv"
    mapping = ROOT / "examples" / "jugglebot" / "map.toml"
    plain = import_log(log, mapping)
    rows = list(csv.reader(log.open()))
    numeric = set(load_map(mapping).numeric_columns())
    cols = {i for i, name in enumerate(rows[0]) if name in numeric}
    europe = [rows[0]] + [
        [c.replace(".", ",") if i in cols else c for i, c in enumerate(r)] for r in rows[1:]
    ]
    path = tmp_path / "log.csv"
    path.write_bytes(codecs.BOM_UTF8 + _text(europe, ";", "\r\n").encode())
    assert import_log(path, mapping) == plain
    path.write_bytes(_text(europe, ",").replace('"', "").encode())
    with pytest.raises(LogImportError, match="decimal commas in a file separated by commas"):
        import_log(path, mapping)
