"""Fuzzing every file reader: whatever the bytes, a reader returns a valid object whose numbers
are all finite, or raises its own documented error (a ValueError subclass) with a clean message —
never RecursionError, OverflowError, UnicodeDecodeError, KeyError, TypeError..., never a pydantic
URL or a numpy repr in the message.

Two kinds of input per reader: (a) arbitrary bytes and text; (b) a valid file mutated — a value
replaced by NaN, Infinity, 1e308, 1e400, -0, a huge integer, a string, null, deep nesting, a key
removed or added, a byte-order mark, CRLF or CR line ends, a byte that is not UTF-8, a cut. The
profile in conftest.py sets the number of examples (HEXCAL_FUZZ=1: 10,000 per test).
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
from dataclasses import dataclass, replace
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from pydantic import BaseModel

from hexcal.acquire.acquisition import LegSample, RecordedPose, TrackerSample
from hexcal.acquire.devices import (
    DevicesConfig,
    DevicesConfigError,
    TrackerConfig,
    load_devices_config,
)
from hexcal.estimate.model_file import load_model, load_robot
from hexcal.estimate.predict_table import Table, TableError, direction, read_table
from hexcal.io.measurements import MeasurementError, Measurements
from hexcal.io.measurements_csv import read_measurements
from hexcal.model.instruments import InstrumentsError, load_instruments
from hexcal.model.robot import RobotFileError
from hexcal.procedure.session import (
    OperatorNote,
    ResultRecord,
    Session,
    SessionFileError,
    SetAside,
    StepProgress,
    load_session,
    session_to_text,
)
from hexcal.procedure.session_model import EncoderReboot
from hexcal.procedure.steps import ProcedureError, load_procedure

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "left-hand-sim"

DEVICES = """\
[tracker]
kind = "ndi"
url = "/dev/ttyUSB0"
baudrate = 115200
timeout_s = 1.0

[can]
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
[[can.legs]]
leg = 2
node_id = 0x22
counts_per_mm = 1000.0
[[can.legs]]
leg = 3
node_id = 0x23
counts_per_mm = 1000.0
[[can.legs]]
leg = 4
node_id = 0x24
counts_per_mm = 1000.0
[[can.legs]]
leg = 5
node_id = 0x25
counts_per_mm = 1000.0
[[can.legs]]
leg = 6
node_id = 0x26
counts_per_mm = 1000.0
sign = -1
zero_mm = -2.5

[still]
duration_s = 0.5
max_position_drift_mm = 0.05
max_angle_drift_deg = 0.01
max_reading_drift_mm = 0.01
max_fault_share = 0.0
"""


def _recorded_pose() -> RecordedPose:
    rng = np.random.default_rng(0)
    q = np.array([1.0, 0, 0, 0])
    ts = [TrackerSample(float(i), rng.normal(size=3), q, 0.01) for i in range(3)]
    ts.append(TrackerSample(9.0, None, None, fault="tool 01 MISSING"))
    ls = [LegSample(float(i), rng.normal(size=6) + 100) for i in range(3)]
    ls.append(LegSample(9.5, np.r_[rng.normal(size=5), np.nan], ("leg 6 sent no position",)))
    return RecordedPose(1.0, rng.normal(size=3), q, rng.normal(size=6) + 100, ts, ls)


@cache
def session_text() -> str:
    """A small session that uses every part of the schema."""
    meas = read_measurements(EXAMPLE / "measurements.csv").subset(slice(0, 3))
    s = Session.from_measurements(
        meas,
        load_robot(EXAMPLE / "robot.json"),
        DevicesConfig(tracker=TrackerConfig(url="/dev/ttyUSB0")),
    )
    s.instruments = load_instruments(EXAMPLE / "instruments.json")
    s.procedure = {"name": "lab", "model": 42, "steps": [{"id": "free", "min_poses": 1}]}
    s.poses.append(s.pose_record(_recorded_pose(), "free", 0, "free", t=50.0, temperature=20.5))
    s.set_aside.append(SetAside(step="free", reason="undone", pose=s.poses[0]))
    s.notes.append(OperatorNote(text="clamp re-tightened"))
    s.progress.append(StepProgress(step="free", status="done", poses=1))
    s.encoder_reboots.append(
        EncoderReboot(leg=3, pose_id=2, jump_mm=7.0, threshold_mm=0.5, beyond=True)
    )
    s.results.append(
        ResultRecord(kind="calibration", model=42, pose_ids=[1, 2], robot=s.robot, summary={})
    )
    return session_to_text(s)


def _head(path: Path, lines: int) -> str:
    return "".join(path.read_text(encoding="utf-8").splitlines(keepends=True)[:lines])


@dataclass(frozen=True)
class Reader:
    """A reader under test: how it is called, its error, the file kind and a valid file."""

    name: str
    read: Any
    error: type[Exception]
    syntax: str  # json | toml | csv
    suffix: str

    def valid(self) -> str:
        return VALID[self.name]()


VALID = {
    "robot": lambda: (EXAMPLE / "robot.json").read_text(encoding="utf-8"),
    "model": lambda: (ROOT / "tests" / "data" / "calibrated.json").read_text(encoding="utf-8"),
    "instruments": lambda: (EXAMPLE / "instruments.json").read_text(encoding="utf-8"),
    "session": session_text,
    "procedure": lambda: (ROOT / "procedures" / "model42-direction-length.toml").read_text(
        encoding="utf-8"
    ),
    "devices": lambda: DEVICES,
    "measurements": lambda: _head(EXAMPLE / "measurements.csv", 12),
    "table": lambda: _head(EXAMPLE / "measurements.csv", 6),
}

READERS = [
    Reader("robot", load_robot, RobotFileError, "json", ".json"),
    Reader("model", load_model, RobotFileError, "json", ".json"),
    Reader("instruments", load_instruments, InstrumentsError, "json", ".json"),
    Reader("session", load_session, SessionFileError, "json", ".json"),
    Reader("procedure", load_procedure, ProcedureError, "toml", ".toml"),
    Reader("devices", load_devices_config, DevicesConfigError, "toml", ".toml"),
    Reader("measurements", read_measurements, MeasurementError, "csv", ".csv"),
    Reader("table", read_table, TableError, "csv", ".csv"),
]
IDS = [r.name for r in READERS]


# -- the property -------------------------------------------------------------------------------


def _finite(obj: Any, where: str = "") -> None:
    if isinstance(obj, BaseModel):
        _finite(obj.model_dump(), where)
    elif isinstance(obj, dict):
        for k, v in obj.items():
            _finite(v, f"{where}.{k}")
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            _finite(v, f"{where}.{i}")
    elif isinstance(obj, np.ndarray):
        if obj.dtype.kind == "f":
            assert np.all(np.isfinite(obj)), where
    elif isinstance(obj, float):
        assert math.isfinite(obj), where


def _check_result(reader: Reader, result: Any) -> None:
    if isinstance(result, Measurements):
        for name in ("t", "position", "quaternion", "readings", "temperature"):
            value = getattr(result, name)
            assert value is None or np.all(np.isfinite(value)), name
        assert np.all((result.pose_id >= 1) & (result.pose_id < 2**53))
    elif isinstance(result, Table):
        # What hexcal predict does with a table before the model: its direction, its columns.
        for name in result.header:
            try:
                values = result.column(name)
            except TableError as exc:
                _check_message(exc)
                continue
            assert np.all(np.isfinite(values)), name
        try:
            direction(result, None)
        except TableError as exc:
            _check_message(exc)
    else:
        _finite(result)


def _check_message(exc: Exception) -> None:
    text = str(exc)
    assert "errors.pydantic.dev" not in text, text
    assert "np.float64" not in text and "np.int64" not in text, text
    assert text.strip(), "an empty message"


def run_reader(reader: Reader, path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` and read it: a valid object, or the reader's own error."""
    path.write_bytes(data)
    try:
        result = reader.read(path)
    except reader.error as exc:
        _check_message(exc)
        assert str(path) in str(exc), f"the message does not name the file: {exc}"
        return
    _check_result(reader, result)


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


# -- mutations ------------------------------------------------------------------------------------

_DEEP = 3000  # beyond any recursion limit

JSON_TOKENS = [
    "NaN",
    "Infinity",
    "-Infinity",
    "1e308",
    "-1e308",
    "1e400",
    "-1e400",
    "1e-400",
    "-0",
    "-0.0",
    "0",
    "-1",
    "0.5",
    "1000001",
    "4294967296",
    "9007199254740992",
    "9223372036854775808",
    "18446744073709551616",
    "1" + "0" * 30,
    "1" * 5000,
    '"x"',
    '""',
    '"NaN"',
    '"' + "a" * 5000 + '"',
    "null",
    "true",
    "false",
    "[]",
    "{}",
    "[null]",
    "[1, 2]",
    "[NaN, 1, 2]",
    "[1e400, 0, 0]",
    "[" * 40 + "]" * 40,
    "[" * _DEEP + "]" * _DEEP,
    '{"a": ' * 40 + "1" + "}" * 40,
    '{"a": ' * _DEEP + "1" + "}" * _DEEP,
]

TOML_TOKENS = [
    "nan",
    "+nan",
    "-nan",
    "inf",
    "+inf",
    "-inf",
    "1e308",
    "1e400",
    "-1e400",
    "-0.0",
    "0",
    "-1",
    "0x7fffffff",
    "99999999999999999999",
    "9223372036854775808",
    "1" * 5000,
    "1_000",
    '"x"',
    '""',
    "'literal'",
    '"""multi\nline"""',
    "true",
    "1979-05-27T07:32:00Z",
    "[]",
    "{}",
    "[1, nan]",
    "[" * 40 + "]" * 40,
    "[" * _DEEP + "]" * _DEEP,
    "{a = " * 40 + "1" + "}" * 40,
    "{a = " * _DEEP + "1" + "}" * _DEEP,
]

CSV_TOKENS = [
    "NaN",
    "nan",
    "inf",
    "-inf",
    "Infinity",
    "1e308",
    "-1e308",
    "1e400",
    "1e-400",
    "-0",
    "-0.0",
    "0",
    "-1",
    "3.0",
    "7",
    "1e6",
    "1000000.5",
    "9007199254740991",
    "9007199254740992",
    "9223372036854775808",
    "1" + "0" * 30,
    "1" * 5000,
    "",
    " ",
    "x",
    "1_000",
    "١",
    "３",
    " 1 ",
    "\t2\t",
    "+5",
    '"',
    '"quoted, with comma"',
    '"open',
    "a,b",
    "\x00",
    "free",
    "length",
    "Direction",
    "x" * 200_000,
]

BAD_BYTES = [b"\x96", b"\xff", b"\xc3", b"\xe2\x82", b"\x00", b"\xed\xa0\x80"]


@st.composite
def post_processed(draw: st.DrawFn, text: str) -> bytes:
    """Encoding-level mutations of a file's text, each now and then (most examples should
    reach the reader's checks of values): BOM, CRLF/CR, a byte that is not UTF-8, a cut."""
    if draw(st.integers(0, 3)) == 0:
        text = text.replace("\n", draw(st.sampled_from(["\r\n", "\r"])))
    data = text.encode("utf-8")
    if draw(st.integers(0, 3)) == 0:
        data = b"\xef\xbb\xbf" + data
    if draw(st.integers(0, 4)) == 0:
        at = draw(st.integers(0, len(data)))
        if draw(st.booleans()):
            data = data[:at] + draw(st.sampled_from(BAD_BYTES)) + data[at:]
        else:
            data = data[:at]
    return data


_PLACEHOLDER = "@@hexcal-token@@"


def _json_paths(node: Any, path: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [path]
    if isinstance(node, dict):
        for k, v in node.items():
            out += _json_paths(v, (*path, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _json_paths(v, (*path, i))
    return out


@st.composite
def mutated_json(draw: st.DrawFn, text: str) -> bytes:
    data = json.loads(text)
    for _ in range(draw(st.integers(1, 3))):
        paths = _json_paths(data)
        path = draw(st.sampled_from(paths))
        op = draw(st.sampled_from(["replace", "replace", "delete", "add"]))
        if not path:
            data = _PLACEHOLDER if op == "replace" else data
            continue
        parent = data
        for p in path[:-1]:
            parent = parent[p]
        key = path[-1]
        if op == "replace":
            parent[key] = _PLACEHOLDER
        elif op == "delete":
            del parent[key]
        elif isinstance(parent, dict):
            parent[draw(st.sampled_from(["extra", "schema_version", "pose_id", key]))] = (
                _PLACEHOLDER
            )
        else:
            parent.append(_PLACEHOLDER)
    out = json.dumps(data, indent=draw(st.sampled_from([None, 1])))
    while f'"{_PLACEHOLDER}"' in out:
        out = out.replace(f'"{_PLACEHOLDER}"', draw(st.sampled_from(JSON_TOKENS)), 1)
    return draw(post_processed(out))


_TOML_ASSIGN = re.compile(r"^(\s*)([A-Za-z0-9_.\-\"']+)(\s*=\s*)(.*)$")


@st.composite
def mutated_toml(draw: st.DrawFn, text: str) -> bytes:
    lines = text.split("\n")
    for _ in range(draw(st.integers(1, 3))):
        i = draw(st.integers(0, len(lines) - 1))
        op = draw(st.sampled_from(["value", "value", "value", "key", "delete", "copy", "insert"]))
        m = _TOML_ASSIGN.match(lines[i])
        if op == "value" and m:
            lines[i] = m.group(1) + m.group(2) + m.group(3) + draw(st.sampled_from(TOML_TOKENS))
        elif op == "key" and m:
            depth = draw(st.sampled_from([1, 31, 40, 100_000]))
            lines[i] = m.group(1) + "a." * depth + m.group(2) + m.group(3) + m.group(4)
        elif op == "delete":
            del lines[i]
        elif op == "copy":
            lines.insert(i, lines[i])
        else:
            extra = draw(
                st.sampled_from(
                    ["extra = 1", "[extra]", "[[steps]]", "[tracker]", "x.y.z = nan", "[can]"]
                )
            )
            lines.insert(i, extra)
        if not lines:
            lines = [""]
    return draw(post_processed("\n".join(lines)))


@st.composite
def mutated_csv(draw: st.DrawFn, text: str) -> bytes:
    rows = list(csv.reader(io.StringIO(text)))
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["cell"] * 6 + ["column", "row", "add-column"]))
        i = draw(st.integers(0, len(rows) - 1))
        if op == "cell" and rows[i]:
            j = draw(st.integers(0, len(rows[i]) - 1))
            rows[i][j] = draw(st.sampled_from(CSV_TOKENS))
        elif op == "column" and rows[0]:
            j = draw(st.integers(0, len(rows[0]) - 1))
            rows = [r[:j] + r[j + 1 :] for r in rows]
        elif op == "row":
            rows.insert(i, list(rows[i]))  # a repeated pose_id, or a second header
        else:
            rows = [[*r, draw(st.sampled_from(CSV_TOKENS))] for r in rows]
    # Joined by hand, not csv.writer: a stray quote must reach the reader as it is.
    out = "\n".join(",".join(r) for r in rows) + "\n"
    return draw(post_processed(out))


MUTATORS = {"json": mutated_json, "toml": mutated_toml, "csv": mutated_csv}

ARBITRARY = st.one_of(
    st.binary(max_size=2000),
    st.text(max_size=2000).map(lambda t: t.encode("utf-8", "surrogatepass")),
)


# -- the tests -------------------------------------------------------------------------------------


@pytest.mark.parametrize("reader", READERS, ids=IDS)
def test_the_valid_files_read(reader: Reader, fuzz_dir: Path) -> None:
    """The starting points of the mutations are valid, so mutations start from a real file."""
    path = fuzz_dir / f"valid-{reader.name}{reader.suffix}"
    path.write_text(reader.valid(), encoding="utf-8")
    _check_result(reader, reader.read(path))


@pytest.mark.fuzz
@pytest.mark.parametrize("reader", READERS, ids=IDS)
@given(data=ARBITRARY)
def test_arbitrary_bytes(reader: Reader, fuzz_dir: Path, data: bytes) -> None:
    run_reader(reader, fuzz_dir / f"arbitrary-{reader.name}{reader.suffix}", data)


@pytest.mark.fuzz
@pytest.mark.parametrize("reader", READERS, ids=IDS)
@given(data=st.data())
def test_mutated_valid_files(reader: Reader, fuzz_dir: Path, data: st.DataObject) -> None:
    mutated = data.draw(MUTATORS[reader.syntax](reader.valid()), label="file")
    run_reader(reader, fuzz_dir / f"mutated-{reader.name}{reader.suffix}", mutated)


# -- the limits at the edges (issue 36): the stroke, a procedure's total ---------------------


@pytest.mark.fuzz
@given(
    steps=st.integers(1, 3000),
    poses=st.integers(1, 10_000),
    legs=st.sampled_from([None, [1], [1, 2, 3, 4, 5, 6]]),
)
def test_a_procedure_is_held_to_what_a_session_holds(fuzz_dir: Path, steps, poses, legs) -> None:
    """Any number of steps and poses per step: loaded only within the cap, else refused
    naming the total and the cap."""
    from hexcal.io.capacity import MAX_PROCEDURE_POSES

    kind = "constraint = 'free'" if legs is None else f"legs = {legs}\nconstraint = 'direction'"
    one = (
        f"[[steps]]\nid = 's{{i}}'\n{kind}\ninstruction = 'x'\nmin_poses = 1\n"
        f"recommended_poses = {poses}\n"
    )
    path = fuzz_dir / "p.toml"
    path.write_text("name = 'n'\nmodel = 42\n" + "".join(one.format(i=i) for i in range(steps)))
    total = steps * poses * (1 if legs is None else len(legs))
    if total <= MAX_PROCEDURE_POSES:
        assert sum(s.n_poses for s in load_procedure(path).expand()) == total
        return
    with pytest.raises(ProcedureError) as exc:
        load_procedure(path)
    assert f"asks for {total:,} poses in all" in str(exc.value)
    assert f"at most {MAX_PROCEDURE_POSES:,} recorded poses" in str(exc.value)


@pytest.mark.fuzz
@given(
    lo=st.floats(-500, 500, allow_nan=False),
    width=st.floats(1, 600, allow_nan=False),
    shift=st.floats(-400, 400, allow_nan=False),
    sigma=st.one_of(st.none(), st.floats(1e-4, 0.1)),
)
def test_the_stroke_refuses_what_lies_beyond_it_and_calls_only_inside_at_the_end(
    lo, width, shift, sigma
) -> None:
    """Any stroke and any shift of the readings: every leg with a reading beyond the stroke by
    more than the margin is named, with how far and a likely cause, and no reading beyond it
    is said to be at the end."""
    from hexcal.diagnosis.limits import at_limits, beyond_stroke, end_margin_mm, stroke_message

    meas = _stroke_table()
    meas = replace(meas, readings=meas.readings + shift)
    design = _stroke_design().model_copy(update={"leg_range_mm": [lo, lo + width]})
    found = beyond_stroke(meas, design, sigma)
    hi = lo + width
    for k in range(6):
        x = meas.readings[:, k]
        margin = end_margin_mm(float(np.ptp(x)), sigma)
        past = np.maximum(x - hi, lo - x)
        named = [f for f in found if f.leg == k + 1]
        assert bool(named) == bool((past > margin).any())
        if named:
            assert named[0].worst_mm == pytest.approx(float(past.max()))
        at_end = {r for e in at_limits(meas, design, sigma).legs if e.leg == k + 1 for r in e.rows}
        assert not at_end & set(np.nonzero(past > margin)[0].tolist())
    if found:
        text = stroke_message(meas, design, found, "t.csv")
        assert text.startswith("t.csv: leg") and "likely causes" in text and "wrong range" in text


@cache
def _stroke_table() -> Measurements:
    return read_measurements(EXAMPLE / "measurements.csv")


@cache
def _stroke_design():
    return load_robot(EXAMPLE / "robot.json")
