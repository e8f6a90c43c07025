"""The plain table read into column arrays gives exactly what the streaming reader gives, and
declines every file it might read otherwise (the streaming reader then names the problems)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hexcal.io import measurements_csv
from hexcal.io.measurements import Measurements, measurements_to_csv_text
from hexcal.io.measurements_fast import read_plain

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "left-hand-sim" / "measurements.csv"


def _streamed(raw: bytes, tmp_path: Path, monkeypatch) -> Measurements:
    path = tmp_path / "m.csv"
    path.write_bytes(raw)
    with monkeypatch.context() as m:
        m.setattr(measurements_csv, "read_plain", lambda raw, path: None)
        return measurements_csv.read_measurements(path)


def test_the_example_reads_the_same(tmp_path, monkeypatch):
    raw = EXAMPLE.read_bytes()
    fast = read_plain(raw, EXAMPLE)
    assert fast is not None and fast == _streamed(raw, tmp_path, monkeypatch)
    assert fast.source == str(EXAMPLE)


def _table(rng: np.random.Generator, n: int) -> Measurements:
    leg = rng.integers(0, 7, n)
    kinds = np.array(["direction", "direction+length", "length"])
    constraint = np.where(leg == 0, "free", kinds[rng.integers(0, 3, n)])
    q = rng.normal(size=(n, 4))
    return Measurements.from_arrays(
        rng.normal(0, 100, (n, 3)),
        q / np.linalg.norm(q, axis=1, keepdims=True),
        rng.normal(150, 30, (n, 6)),
        leg=leg,
        constraint=constraint,
        t=np.round(rng.uniform(0, 1e4, n), 3),
        temperature=np.round(rng.normal(20, 1, n), 2),
        extra={"operator": np.where(rng.random(n) < 0.5, "Ann", " Bo b "), "note": "x"},
    )


@given(
    seed=st.integers(0, 2**32 - 1),
    spaces=st.booleans(),
    crlf=st.booleans(),
    bom=st.booleans(),
    blank=st.booleans(),
)
def test_formatting_variants_read_the_same(
    seed, spaces, crlf, bom, blank, tmp_path_factory, monkeypatch
):
    rng = np.random.default_rng(seed)
    text = measurements_to_csv_text(_table(rng, int(rng.integers(1, 40))))
    if spaces:
        text = text.replace(",", " , ")
    if blank:
        text = text.replace("\n", "\n\n", 3)
    if crlf:
        text = text.replace("\n", "\r\n")
    raw = (b"\xef\xbb\xbf" if bom else b"") + text.encode()
    fast = read_plain(raw, Path("m.csv"))
    assert fast is not None
    assert fast == _streamed(raw, tmp_path_factory.mktemp("t"), monkeypatch)


def _field(text: str, column: str, value: str) -> str:
    """``text`` with the first row's field ``column`` set to ``value``."""
    lines = text.split("\n")
    header = lines[0].split(",")
    fields = lines[1].split(",")
    fields[header.index(column)] = value
    lines[1] = ",".join(fields)
    return "\n".join(lines)


@pytest.mark.parametrize(
    "change",
    [
        lambda t: _field(t, "step", '"quoted"'),
        lambda t: _field(t, "constraint", "FREE"),  # not a constraint
        lambda t: _field(t, "pose_id", "2"),  # a repeated pose id
        lambda t: t + "1,2,3\n",  # a short row
        lambda t: _field(t, "x", "nan"),  # not finite
        lambda t: _field(t, "t", "1_000.5"),  # a digit separator
        lambda t: _field(t, "leg", "3.0"),  # an integer written as a float (read, row by row)
        lambda t: _field(t, "step", " "),  # an empty step
        lambda t: t.replace("\n", "\r", 2),  # old Mac line ends
    ],
)
def test_what_it_declines(change):
    text = measurements_to_csv_text(_table(np.random.default_rng(0), 20))
    changed = change(text)
    assert changed != text
    assert read_plain(changed.encode(), Path("m.csv")) is None
