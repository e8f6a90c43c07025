"""Reading ``measurements.csv`` (docs/formats.md): the streaming reader
(:func:`read_measurements`), with the rules a row must keep (:class:`MeasurementRow`, pydantic
v2, in :mod:`hexcal.io.measurement_rows`) and the file's CSV dialect
(:mod:`hexcal.io.csv_dialect`).

Reading streams the file row by row into typed arrays, so memory stays about the file's size
(a 200 MB table reads in well under 1 GB); rows are checked a block at a time against the rules
of :class:`MeasurementRow`, which validates every row of a block that breaks one, so that *all*
bad rows are reported in one :class:`~hexcal.io.measurements.MeasurementError` naming the file,
the line and the column. Values are held to the ranges of :mod:`hexcal.io.safe_read` (positions
and readings ±1 km, times ±1e9 s, temperatures −273.15..1000 degC, pose ids 1 .. 2**53 − 1).

The table itself, its errors and the writer are in :mod:`hexcal.io.measurements`, which this
module imports (never the other way round).
"""

from __future__ import annotations

import codecs
import csv
import io
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import ValidationError

from hexcal.io.csv_dialect import HEAD_BYTES, Dialect, DialectError, sniff, to_point

# MeasurementRow: the row rules, importable from here too.
from hexcal.io.fileio import OutputFileError
from hexcal.io.measurement_rows import MeasurementRow, row_issues
from hexcal.io.measurements import (
    _KNOWN_COLUMNS,
    CONSTRAINTS,
    MAX_MESSAGES,
    POSITION_COLUMNS,
    QUATERNION_COLUMNS,
    QUATERNION_TOLERANCE,
    READING_COLUMNS,
    REQUIRED_COLUMNS,
    Issue,
    MeasurementError,
    Measurements,
    _object_array,
    _raise_issues,
)
from hexcal.io.measurements_fast import read_plain
from hexcal.io.safe_read import (
    MAX_COORDINATE_MM,
    MAX_POSE_ID,
    MAX_TEMPERATURE_C,
    MAX_TIME_S,
    MIN_TEMPERATURE_C,
    legacy_hint,
    open_binary,
)
from hexcal.vocabulary import Constraint

#: Largest table read by the compiled column reader (a million poses is about 200 MB; 120,000
#: about 25 MB): it holds the file's text a few times over, the streaming reader about once.
FAST_MAX_BYTES = 64 * 1024 * 1024

# --------------------------------------------------------------------------------------------
# Reading

#: Rows checked together: enough for numpy to pay off, few enough that a block's text (about
#: 50 bytes a field as Python strings) stays a few MB.
_BLOCK_ROWS = 4096


#: Bytes read at a time when looking for an undecodable byte.
_DECODE_BLOCK = 1 << 20
#: Bytes read at a time when counting line ends.
_COUNT_BLOCK = 1 << 22


class _Slow(Exception):
    """A block breaks a rule: validate it row by row for the messages."""


def _undecodable(path: Path) -> MeasurementError:
    """The error for the file's first byte that is not UTF-8: its offset, line and column.

    Called only once decoding failed, so reading pays nothing for it: the file is read again
    in binary, a block at a time, through an incremental decoder."""
    decoder = codecs.getincrementaldecoder("utf-8")()
    offset = lines = 0  # bytes and line ends before the block
    tail = b""  # the current line's bytes before the block (its last MB at most)
    first_line: bytes | None = None
    with path.open("rb") as fh:
        while True:
            block = fh.read(_DECODE_BLOCK)
            buffered = len(decoder.getstate()[0])  # an incomplete character's first bytes
            try:
                decoder.decode(block, final=not block)
            except UnicodeDecodeError as exc:
                at = offset - buffered + exc.start  # in the file
                break
            if not block:  # pragma: no cover - the text reader found a bad byte
                return MeasurementError.single(path, None, None, "is not UTF-8 text")
            data = tail + block
            if first_line is None and b"\n" in data:
                first_line = data.split(b"\n", 1)[0]
            lines += block.count(b"\n")
            tail = data[data.rfind(b"\n") + 1 :][-_DECODE_BLOCK:]
            offset += len(block)
    data = tail + block
    i = at - (offset - len(tail))  # the bad byte in data
    line = lines + data.count(b"\n", 0, i) + 1
    if first_line is None:
        first_line = data.split(b"\n", 1)[0]
    column = None
    if line > 1:  # best effort: the header name of the field holding the byte
        before = data[data.rfind(b"\n", 0, i) + 1 : i].decode("utf-8", "replace")
        try:
            header = next(csv.reader([first_line.decode("utf-8", "replace").strip()]), [])
            index = max(len(next(csv.reader([before]), [])) - 1, 0)
        except csv.Error:
            header, index = [], 0
        if index < len(header):
            column = header[index].strip().lstrip("\ufeff")
    return MeasurementError.single(
        path,
        line,
        column,
        f"byte {at} (0x{data[i]:02x}) is not UTF-8 text; save the file as UTF-8 (e.g. 'CSV UTF-8')"
        + legacy_hint(data[i : i + 4]),
    )


def _header_issues(header: list[str], line: int) -> list[Issue]:
    issues = []
    seen: dict[str, int] = {}
    for k, name in enumerate(header):
        if not name:
            issues.append(
                Issue(
                    f"header column {k + 1} has no name; name it or delete the column "
                    "(a trailing comma?)",
                    line=line,
                )
            )
        elif name in seen:
            issues.append(
                Issue(
                    f"column name '{name}' appears twice (columns {seen[name] + 1} and {k + 1}); "
                    "rename or delete one",
                    line=line,
                    column=name,
                )
            )
        else:
            seen[name] = k
    missing = [c for c in REQUIRED_COLUMNS if c not in seen]
    if missing:
        lower = {name.lower(): name for name in seen}
        named = [
            f"'{c}'" + (f" (found '{lower[c]}': names are lower case)" if c in lower else "")
            for c in missing
        ]
        issues.append(
            Issue(
                f"required column(s) {', '.join(named)} missing from the header; the header "
                f"must name {','.join(REQUIRED_COLUMNS)} (temperature and extra columns "
                "optional)",
                line=line,
                column=missing[0],
            )
        )
    return issues


def _count_issue(fields: list[str], header: list[str], line: int) -> Issue:
    n, ncol = len(fields), len(header)
    if n < ncol:
        return Issue(
            f"{n} fields but the header has {ncol} columns: '{header[n]}' and after are missing; "
            "complete the row or remove it",
            line=line,
            column=header[n],
        )
    trailing = " (a trailing comma?)" if not any(fields[ncol:]) else ""
    return Issue(
        f"{n} fields but the header has {ncol} columns: {n - ncol} field(s) after the last "
        f"column '{header[-1]}'{trailing}; remove them, or name them in the header",
        line=line,
    )


@dataclass
class RowBlock:
    """Consecutive valid rows of the file, typed (units as in :class:`Measurements`): what
    :func:`stream_measurements` hands its sink."""

    line: np.ndarray  #: (k,) the line each row starts on
    pose_id: np.ndarray
    t: np.ndarray
    step: list[str]
    leg: np.ndarray
    constraint: list[str]
    position: np.ndarray
    quaternion: np.ndarray
    readings: np.ndarray
    temperature: np.ndarray | None
    extra: list[list[str]]  #: per extra column, in header order


class _TableReader:
    """Turns the file's data rows into typed arrays a block at a time.

    A block that keeps every rule is converted with numpy (the common case, and what keeps a
    200 MB file fast); a block that breaks one is validated row by row with
    :class:`MeasurementRow`, whose messages the error reports. Once a row is bad the values
    are no longer kept (the read will fail), only the ids and lines that duplicates are checked
    against."""

    def __init__(
        self, header: list[str], path: Path, sink: Callable[[RowBlock], None] | None = None
    ):
        self.header = header
        self.sink = sink
        self.path = path
        self.at = {c: k for k, c in enumerate(header)}
        self.fields = [c for c in header if c in _KNOWN_COLUMNS]
        self.extra_names = [c for c in header if c not in _KNOWN_COLUMNS]
        self.has_temperature = "temperature" in self.at
        self.blocks: list[RowBlock] = []
        self.ids: list[np.ndarray] = []
        self.lines: list[np.ndarray] = []
        self.issues: list[Issue] = []  # the first MAX_MESSAGES row problems
        self.problems = 0  # all of them
        self.rows = 0
        self.texts: dict[str, str] = {}  # one str object per distinct step/constraint

    def flush(self, rows: list[tuple[int, list[str]]]) -> None:
        """Take a block of data rows: (line, fields as read, not stripped)."""
        if not rows:
            return
        self.rows += len(rows)
        try:
            block = self._fast(rows)
        except _Slow:
            block = self._slow(rows)
        self.ids.append(block.pose_id)
        self.lines.append(block.line)
        if self.problems:
            self.blocks.clear()
        elif self.sink is not None:  # streamed: the block goes on, only its ids stay
            self.sink(block)
        else:
            self.blocks.append(block)

    # -- the fast path: a block with no problem, checked by columns --------------------------

    def _column(self, cols: list[tuple[str, ...]], name: str) -> tuple[str, ...]:
        col = cols[self.at[name]]
        joined = "".join(col)
        # As _parse_number/_parse_integer: no empty field, ASCII only, no digit separators
        # (float() and int() would take '1_000' and non-ASCII digits).
        if "" in col or "_" in joined or not joined.isascii():
            raise _Slow
        return col

    def _floats(self, cols: list[tuple[str, ...]], names: Sequence[str]) -> np.ndarray:
        try:
            out = np.array([list(map(float, self._column(cols, c))) for c in names]).T
        except ValueError:
            raise _Slow from None
        return out

    def _ints(self, cols: list[tuple[str, ...]], name: str, low: int, high: int) -> np.ndarray:
        try:
            values = np.array(list(map(int, self._column(cols, name))), dtype=np.int64)
        except (ValueError, OverflowError):  # '3.0' is valid: the slow path reads it
            raise _Slow from None
        if not np.all((values >= low) & (values <= high)):
            raise _Slow
        return values

    def _within(self, values: np.ndarray, low: float, high: float) -> np.ndarray:
        if not np.all((values >= low) & (values <= high)):  # False for NaN too
            raise _Slow
        return values

    def _texts(self, col: Sequence[str]) -> list[str]:
        """Stripped text, one str object per distinct value (a step name is shared by many
        rows: memory)."""
        col = list(map(str.strip, col))
        cache = self.texts
        if len(cache) > 10_000:  # steps are a few dozen names; do not hoard unique ones
            return col
        return [cache.setdefault(v, v) for v in col]

    def _fast(self, rows: list[tuple[int, list[str]]]) -> RowBlock:
        ncol = len(self.header)
        if any(len(fields) != ncol for _, fields in rows):
            raise _Slow
        cols = list(zip(*(fields for _, fields in rows), strict=True))
        pose_id = self._ints(cols, "pose_id", 1, MAX_POSE_ID)
        leg = self._ints(cols, "leg", 0, 6)
        t = self._within(self._floats(cols, ["t"])[:, 0], -MAX_TIME_S, MAX_TIME_S)
        position = self._floats(cols, POSITION_COLUMNS)
        readings = self._floats(cols, READING_COLUMNS)
        self._within(position, -MAX_COORDINATE_MM, MAX_COORDINATE_MM)
        self._within(readings, -MAX_COORDINATE_MM, MAX_COORDINATE_MM)
        quaternion = self._floats(cols, QUATERNION_COLUMNS)
        with np.errstate(over="ignore", invalid="ignore"):
            norm = np.sqrt(np.sum(quaternion * quaternion, axis=1))
        # A hair inside the tolerance: a row at its very edge goes to MeasurementRow, whose
        # sum (in another order) has the last word.
        edge = QUATERNION_TOLERANCE * (1 - 1e-9)
        self._within(norm, 1.0 - edge, 1.0 + edge)
        temperature = None
        if self.has_temperature:
            temperature = self._floats(cols, ["temperature"])[:, 0]
            self._within(temperature, MIN_TEMPERATURE_C, MAX_TEMPERATURE_C)
        # Text may hold any character ('leg1_direction', 'Bein 1'): stripped, never empty.
        step = self._texts(cols[self.at["step"]])
        constraint = self._texts(cols[self.at["constraint"]])
        if "" in step or not set(constraint) <= set(CONSTRAINTS):
            raise _Slow
        free_ = Constraint.FREE.value  # once, as plain text: the fastest comparison
        free = np.array([c == free_ for c in constraint], dtype=bool)
        if np.any(free != (leg == 0)):
            raise _Slow
        return RowBlock(
            line=np.array([line for line, _ in rows], dtype=np.int64),
            pose_id=pose_id,
            t=t,
            step=step,
            leg=leg,
            constraint=constraint,
            position=position,
            quaternion=quaternion,
            readings=readings,
            temperature=temperature,
            extra=[list(map(str.strip, cols[self.at[c]])) for c in self.extra_names],
        )

    # -- the slow path: row by row, every problem named ----------------------------------------

    def _issue(self, issue: Issue) -> None:
        self.problems += 1
        if len(self.issues) < MAX_MESSAGES:
            self.issues.append(issue)

    def _slow(self, rows: list[tuple[int, list[str]]]) -> RowBlock:
        header, order = self.header, self.at
        valid: list[tuple[int, MeasurementRow, list[str]]] = []
        for line, fields in rows:
            values = [f.strip() for f in fields]
            if len(values) != len(header):
                self._issue(_count_issue(values, header, line))
                continue
            by_name = dict(zip(header, values, strict=True))
            try:
                row = MeasurementRow.model_validate({c: by_name[c] for c in self.fields})
            except ValidationError as exc:
                found = row_issues(exc, line, by_name)
                for issue in sorted(found, key=lambda i: order.get(i.column or "", len(order))):
                    self._issue(issue)
                continue
            valid.append((line, row, [by_name[c] for c in self.extra_names]))
        rs = [r for _, r, _ in valid]
        return RowBlock(
            line=np.array([line for line, _, _ in valid], dtype=np.int64),
            pose_id=np.array([r.pose_id for r in rs], dtype=np.int64),
            t=np.array([r.t for r in rs], dtype=float),
            step=self._texts([r.step for r in rs]),
            leg=np.array([r.leg for r in rs], dtype=np.int64),
            constraint=self._texts([r.constraint for r in rs]),
            position=np.array([[r.x, r.y, r.z] for r in rs], dtype=float).reshape(-1, 3),
            quaternion=np.array([[r.qw, r.qx, r.qy, r.qz] for r in rs], dtype=float).reshape(-1, 4),
            readings=np.array(
                [[r.rho1, r.rho2, r.rho3, r.rho4, r.rho5, r.rho6] for r in rs], dtype=float
            ).reshape(-1, 6),
            temperature=(
                np.array([r.temperature for r in rs], dtype=float) if self.has_temperature else None
            ),
            extra=[[e[k] for _, _, e in valid] for k in range(len(self.extra_names))],
        )

    # -- the table ------------------------------------------------------------------------------

    def checked_ids(self) -> np.ndarray:
        """Every row's pose id, (N,), once no row breaks a rule and no id repeats; else the
        :class:`MeasurementError` naming the first problems."""
        ids = np.concatenate(self.ids) if self.ids else np.zeros(0, np.int64)
        self.ids = [ids]
        duplicates: list[Issue] = []
        repeated = 0
        # Sorted ids tell at 9 bytes a row whether any repeats; only then are the rows found
        # and named (np.unique's index arrays take five times that: a streamed table's peak).
        if self.problems or _any_repeat(ids):
            lines = np.concatenate(self.lines) if self.lines else np.zeros(0, np.int64)
            duplicates, repeated = _repeated_ids(ids, lines)
        if self.problems or repeated:
            # Both lists are in line order and hold the first MAX_MESSAGES of their kind, so
            # the first MAX_MESSAGES of the merge are the file's first problems.
            issues = sorted(self.issues + duplicates, key=lambda i: i.line or 0)[:MAX_MESSAGES]
            total = self.problems + repeated
            raise MeasurementError(issues, self.path, omitted=total - len(issues))
        return ids

    def finish(self) -> Measurements:
        ids = self.checked_ids()
        b = self.blocks

        def cat(name: str) -> np.ndarray:
            return np.concatenate([getattr(x, name) for x in b])

        def texts(values: list[str]) -> np.ndarray:
            return _object_array(values)

        return Measurements(
            pose_id=ids,
            t=cat("t"),
            step=texts([s for x in b for s in x.step]),
            leg=cat("leg"),
            constraint=texts([s for x in b for s in x.constraint]),
            position=cat("position"),
            quaternion=cat("quaternion"),
            readings=cat("readings"),
            temperature=cat("temperature") if self.has_temperature else None,
            extra={
                c: texts([s for x in b for s in x.extra[k]]) for k, c in enumerate(self.extra_names)
            },
            columns=tuple(self.header),
            source=str(self.path),
        )


def _any_repeat(ids: np.ndarray) -> bool:
    ordered = np.sort(ids)
    return bool(np.any(ordered[1:] == ordered[:-1]))


def _repeated_ids(ids: np.ndarray, lines: np.ndarray) -> tuple[list[Issue], int]:
    """The rows whose pose_id an earlier row already has (the first MAX_MESSAGES, in line
    order), and how many there are; ``ids`` and ``lines`` in file order."""
    if len(ids) < 2:
        return [], 0
    _, first, group = np.unique(ids, return_index=True, return_inverse=True)
    group = group.reshape(-1)
    repeats = np.flatnonzero(first[group] != np.arange(len(ids)))
    issues = [
        Issue(
            f"pose_id {int(ids[i])} was already used on line {int(lines[first[group[i]]])}; "
            "pose ids must be unique: renumber or remove the row",
            line=int(lines[i]),
            column="pose_id",
        )
        for i in repeats[:MAX_MESSAGES]
    ]
    return issues, len(repeats)


#: The columns holding numbers (where a decimal comma is read as a point).
NUMERIC_COLUMNS = ("pose_id", "t", "leg", *POSITION_COLUMNS, *QUATERNION_COLUMNS,
                   *READING_COLUMNS, "temperature")  # fmt: skip


def read_measurements(path: str | Path, notices: list[str] | None = None) -> Measurements:
    """Read and validate measurements.csv (docs/formats.md).

    Raises :class:`MeasurementError` listing every bad row (up to :data:`MAX_MESSAGES`), each
    with file, line (header = line 1) and column; also for a missing, unreadable, non-UTF-8,
    empty or too large (:data:`hexcal.io.safe_read.KINDS`) file. Floats keep the exact value
    written; extra columns keep their text. The file is streamed: memory stays about its size.

    The CSV dialect is found from the file's first lines (:mod:`hexcal.io.csv_dialect`):
    semicolons or tabs, decimal commas, a byte-order mark, UTF-16, Excel's ``sep=`` line and
    empty padding columns are read as they are, and said in ``notices`` when given.
    """
    table = _read(Path(path), notices, None)
    assert isinstance(table, Measurements)
    return table


def stream_measurements(
    path: str | Path,
    sink: Callable[[list[str], RowBlock], None],
    notices: list[str] | None = None,
) -> int:
    """Read measurements.csv as :func:`read_measurements` does, but hand each block of valid
    rows to ``sink(header, block)`` as it is read instead of keeping it: memory stays a block
    of rows (and 16 bytes a row for the check of repeated pose ids), whatever the file's size.
    The number of rows; a file with a bad row raises :class:`MeasurementError` as
    :func:`read_measurements` does, after ``sink`` may have had the rows before it (the caller
    throws those away). An error ``sink`` raises goes through unchanged."""
    ids = _read(Path(path), notices, sink)
    assert isinstance(ids, np.ndarray)
    return len(ids)


def line_ends(path: str | Path) -> int:
    """The line ends (``\\n``, ``\\r\\n``, a lone ``\\r``) in the table at ``path``, counted
    in its bytes a block at a time, nothing parsed: at least its data rows (the header ends with
    one, and every row but the last), so a bound on them from above; blank lines and line breaks
    inside quoted cells only add to it. Memory: a block; time: reading the file (about a
    second for 500 MB from the page cache)."""
    path = Path(path)
    ends = 0
    carriage = False  # the previous block ended with a carriage return
    with open_binary(path, "measurements", _error_of(path)) as fh:
        try:
            while block := fh.read(_COUNT_BLOCK):
                # \r\n counts once: every \n, and every \r no \n follows.
                ends += block.count(b"\n") + block.count(b"\r") - block.count(b"\r\n")
                if carriage and block[:1] == b"\n":
                    ends -= 1
                carriage = block[-1:] == b"\r"
        except OSError as exc:
            raise _error_of(path)(f"cannot be read ({exc.strerror or exc})") from None
    return ends


def count_rows(path: str | Path) -> int:
    """The data rows the streaming reader finds in the table at ``path`` (blank rows left out,
    as it leaves them out), in its dialect, parsed but not checked: what a table of more rows
    than a session holds is refused with before anything is written. A file that is not CSV
    text is refused as :func:`read_measurements` refuses it. Memory: a row."""
    path = Path(path)
    with open_binary(path, "measurements", _error_of(path)) as fh:
        dialect, _ = _dialect(fh, path)
        stream = io.TextIOWrapper(fh, encoding=dialect.encoding, newline="")
        reader = dialect.reader(stream)
        try:
            rows = sum(1 for fields in reader if not _blank(fields))
        except csv.Error as exc:
            raise MeasurementError.single(
                path, reader.line_num + dialect.skip, None, f"not valid CSV ({exc}); fix the line"
            ) from None
        except UnicodeDecodeError:
            raise _undecodable(path) from None
        except OSError as exc:
            raise _error_of(path)(f"cannot be read ({exc.strerror or exc})") from None
    return max(rows - 1, 0)  # the header


def _blank(fields: list[str]) -> bool:
    """A row with no data at all: a blank line, or the all-comma rows spreadsheets append.
    (Fields are stripped where they are used: the fast path leaves numbers as they are, since
    float() and int() ignore the same spaces str.strip() removes.)"""
    return not fields or (not fields[0].strip() and not "".join(fields).strip())


def _error_of(path: Path) -> Callable[[str], MeasurementError]:
    def error(message: str) -> MeasurementError:
        return MeasurementError.single(path, None, None, message.removeprefix(f"{path}: "))

    return error


def _dialect(fh: io.BufferedReader, path: Path) -> tuple[Dialect, int]:
    """The dialect of the table open in ``fh`` (read from its first lines; ``fh`` is left at
    its start) and the file's size, bytes."""
    try:
        head = fh.read(HEAD_BYTES)
        size = os.fstat(fh.fileno()).st_size
        fh.seek(0)
    except OSError as exc:
        raise _error_of(path)(f"cannot be read ({exc.strerror or exc})") from None
    try:
        return sniff(head, REQUIRED_COLUMNS, NUMERIC_COLUMNS), size
    except DialectError as exc:
        raise MeasurementError.single(path, 2, None, str(exc)) from None


def _read(
    path: Path,
    notices: list[str] | None,
    sink: Callable[[list[str], RowBlock], None] | None,
) -> Measurements | np.ndarray:
    """The table (``sink`` None) or, streamed into ``sink``, its pose ids."""
    error = _error_of(path)
    with open_binary(path, "measurements", error) as fh:
        dialect, size = _dialect(fh, path)
        # A plain, valid table in hexcal's own dialect goes straight into column arrays (in
        # memory a few times its size, so only up to FAST_MAX_BYTES: 640 MB at the edge); any
        # other file, and every file streamed into a sink, is read row by row below, every
        # problem named, memory about its size (a sink's: a block of rows).
        if sink is None and dialect.standard and size <= FAST_MAX_BYTES:
            try:
                raw = fh.read()
                fh.seek(0)
            except OSError as exc:
                raise error(f"cannot be read ({exc.strerror or exc})") from None
            plain = read_plain(raw, path)
            del raw
            if plain is not None:
                return plain
        # newline="" keeps line ends as they are, as the csv module wants; utf-8-sig drops a
        # leading byte-order mark (spreadsheet exports).
        stream = io.TextIOWrapper(fh, encoding=dialect.encoding, newline="")
        try:
            table = _read_table(stream, path, dialect, sink)
            out = table.finish() if sink is None else table.checked_ids()
        except UnicodeDecodeError:
            raise _undecodable(path) from None
        except OutputFileError:
            raise  # the sink's own write failed: it names its file
        except OSError as exc:
            raise error(f"cannot be read ({exc.strerror or exc})") from None
    if not dialect.standard and notices is not None:
        notices.append(f"{path}: read as a table {dialect.describe()}")
    return out


def _bound(
    sink: Callable[[list[str], RowBlock], None] | None, header: list[str]
) -> Callable[[RowBlock], None] | None:
    if sink is None:
        return None
    return lambda block: sink(header, block)


def _read_table(
    stream: io.TextIOWrapper,
    path: Path,
    dialect: Dialect,
    sink: Callable[[list[str], RowBlock], None] | None,
) -> _TableReader:
    reader = dialect.reader(stream)
    skip = dialect.skip
    table: _TableReader | None = None
    pending: list[tuple[int, list[str]]] = []
    header_line = 1 + skip
    start = 1
    numeric: list[int] = []
    width = 0
    try:
        for fields in reader:
            line, start = start + skip, reader.line_num + 1
            if _blank(fields):
                continue
            if table is not None:
                fields = dialect.trim(fields, width)
                if numeric:
                    for j in numeric:
                        if j < len(fields):
                            fields[j] = to_point(fields[j])
                pending.append((line, fields))
                if len(pending) >= _BLOCK_ROWS:
                    table.flush(pending)
                    pending = []
                continue
            header_line = line
            header = [f.strip() for f in fields]
            header = header[: len(header) - dialect.padding]
            _raise_issues(_header_issues(header, line), path)
            table = _TableReader(header, path, _bound(sink, header))
            width = len(header)
            if dialect.decimal == ",":
                numeric = [k for k, c in enumerate(header) if c in NUMERIC_COLUMNS]
    except csv.Error as exc:
        raise MeasurementError.single(
            path, reader.line_num + skip, None, f"not valid CSV ({exc}); fix the line or remove it"
        ) from None
    if table is None:
        raise MeasurementError.single(
            path, 1, None, f"the file is empty; it needs the header {','.join(REQUIRED_COLUMNS)}"
        )
    table.flush(pending)
    if table.rows == 0:
        raise MeasurementError.single(
            path, header_line + 1, None, "no data rows after the header; record at least one pose"
        )
    return table
