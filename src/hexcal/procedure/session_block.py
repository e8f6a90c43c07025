"""A session's imported table in its pose block (:mod:`hexcal.io.pose_block`): streamed in from
a CSV by ``session import``, read back as the measurement table, written beside a session
file that does not have it yet (docs/formats.md, "The pose block").

The block is named after the session file and its checksum (``s.json.<sha>.poses.npy``) and is
never changed once written: a session saved again keeps referring to it, so a crash during a
save leaves the previous session file with its block, or the new one with it. Its size is
held to :data:`hexcal.io.capacity.MAX_IMPORTED_POSES`: ``session import`` refuses a larger
table before anything is written (:func:`check_table_size`), the writer as it streams in
(nothing is left), and the reader.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hexcal.io import capacity
from hexcal.io.measurements import MeasurementError, Measurements
from hexcal.io.measurements_csv import RowBlock, count_rows, line_ends, stream_measurements
from hexcal.io.pose_block import (
    SUFFIX,
    PoseBlockError,
    PoseBlockWriter,
    decode_texts,
    read_block,
)
from hexcal.procedure.session_model import (
    _TABLE_COLUMNS,
    PoseBlock,
    Session,
    SessionFileError,
)

#: Rows written to a block at a time from a table in memory.
_CHUNK_ROWS = 65_536
#: Bytes read at a time when looking for a block's name in the folder's other files.
_SCAN_BYTES = 1 << 22


def text_columns(columns: list[str]) -> list[str]:
    """The block's text columns for a session whose table has header ``columns``."""
    return ["step", "constraint", *(c for c in columns if c not in _TABLE_COLUMNS)]


def _limit_text() -> str:
    return (
        f"a session holds at most {capacity.MAX_IMPORTED_POSES:,} imported poses "
        "(hexcal.io.capacity.MAX_IMPORTED_POSES, what every hexcal command reads)"
    )


def read_table(path: Path, block: PoseBlock, columns: list[str]) -> Measurements:
    """The imported table held in the pose block at ``path`` (described by ``block``, the
    session's header ``columns``), every row checked as a table read from a CSV is; a block
    beyond the limit, damaged, or whose rows break the table's rules is refused naming it."""
    if block.poses > capacity.MAX_IMPORTED_POSES:
        raise SessionFileError(
            f"{path}: {block.poses:,} poses; {_limit_text()}. It is left untouched: import a "
            "part of the table per session, or calibrate straight from the table"
        )
    names = text_columns(columns)
    if list(block.texts) != names:
        raise SessionFileError(
            f"{path}: the session file lists the text columns {list(block.texts)} for its pose "
            f"block where its columns give {names}; the file is left untouched"
        )
    try:
        rec = read_block(path, block.poses, block.sha256, len(names))
        codes = rec["texts"]
        texts = [decode_texts(path, codes[:, j], block.texts[c], c) for j, c in enumerate(names)]
    except PoseBlockError as exc:
        raise SessionFileError(str(exc)) from None
    del codes
    try:
        table = Measurements(
            pose_id=rec["pose_id"],
            t=rec["t"],
            step=texts[0],
            leg=rec["leg"],
            constraint=texts[1],
            position=rec["position"],
            quaternion=rec["quaternion"],
            readings=rec["readings"],
            temperature=rec["temperature"] if "temperature" in columns else None,
            extra=dict(zip(names[2:], texts[2:], strict=True)),
            columns=tuple(columns),
            source=str(path),
        )
    except (MeasurementError, ValueError) as exc:
        raise SessionFileError(
            f"{path}: its poses break the table's rules ({exc}); the file is left untouched"
        ) from None
    if len(np.unique(table.pose_id)) != len(table):
        raise SessionFileError(
            f"{path}: a pose id repeats in the pose block; pose ids must be unique, as in the "
            "table; the file is left untouched"
        )
    return table


def _refusal(source: Path, out: Path, count: str) -> SessionFileError:
    return SessionFileError(
        f"{source}: {count} poses; {_limit_text()}, so {out} was not written: import a part of "
        "the table (a step, a stretch of time) per session, or calibrate and diagnose straight "
        "from the table"
    )


def _too_many(source: Path, out: Path) -> Callable[[], Exception]:
    return lambda: _refusal(source, out, f"more than {capacity.MAX_IMPORTED_POSES:,}")


def check_table_size(source: Path, out: Path) -> None:
    """Refuse the table ``source`` when it holds more poses than a session does, before
    anything is written (``out``, the session file, is only named). Its line ends bound its
    rows from above (:func:`~hexcal.io.measurements_csv.line_ends`, the file's bytes read
    once); only a table whose bound passes the limit is parsed to count its rows exactly
    (:func:`~hexcal.io.measurements_csv.count_rows`, nothing checked, nothing written). A
    table that passes is checked row by row as it streams in, and held to the limit there too
    (a file that grew in between)."""
    if line_ends(source) <= capacity.MAX_IMPORTED_POSES:
        return
    rows = count_rows(source)
    if rows > capacity.MAX_IMPORTED_POSES:
        raise _refusal(source, out, f"{rows:,}")


def _attach(session: Session, writer: PoseBlockWriter, out: Path) -> None:
    info = writer.finish()
    session.pose_block = PoseBlock(
        file=info.name, poses=info.poses, sha256=info.sha256, texts=info.texts
    )
    attach(session, out.with_name(info.name))


def attach(session: Session, path: Path) -> None:
    """Make the pose block at ``path`` (as ``session.pose_block`` describes it) the session's
    table: read when first asked for (:meth:`Session.imported`)."""
    block = session.pose_block
    assert block is not None
    session._block_path = path
    session._table_source = lambda: read_table(path, block, session.columns)


def stream_table(source: Path, session: Session, out: Path, notices: list[str] | None) -> int:
    """Stream the table ``source`` (measurements.csv) into a new pose block beside the session
    file ``out``, a block of rows at a time, and make it ``session``'s table (its header
    becomes the session's ``columns``). The number of poses. A bad row, a table beyond the
    limit or a failed write leaves nothing behind."""
    writer: PoseBlockWriter | None = None

    def sink(header: list[str], rows: RowBlock) -> None:
        nonlocal writer
        if writer is None:
            session.columns = list(header)
            writer = PoseBlockWriter(
                out, text_columns(session.columns), capacity.MAX_IMPORTED_POSES,
                _too_many(source, out),
            )  # fmt: skip
        writer.add(
            rows.pose_id,
            rows.t,
            rows.leg,
            rows.position,
            rows.quaternion,
            rows.readings,
            rows.temperature,
            [rows.step, rows.constraint, *rows.extra],
        )

    try:
        n = stream_measurements(source, sink, notices)
        if writer is None:  # the reader refuses a table without rows; kept for the types
            raise SessionFileError(f"{source}: no data rows; {out} was not written")
        _attach(session, writer, out)
    except BaseException:
        if writer is not None:
            writer.discard()
        raise
    return n


def write_block(session: Session, out: Path) -> Path | None:
    """Write ``session``'s imported table as a pose block beside the session file ``out``
    unless its block is there already: the new block's path, or None when nothing was
    written. ``session.pose_block`` then names it."""
    if session.pose_block is None and session._table is None:
        return None
    at = session._block_path
    if at is not None and at.parent.resolve() == out.parent.resolve() and at.exists():
        return None
    table = session.imported()
    assert table is not None
    names = text_columns(session.columns)
    writer = PoseBlockWriter(
        out, names, capacity.MAX_IMPORTED_POSES, _too_many(Path("the table"), out)
    )
    try:
        for a in range(0, len(table), _CHUNK_ROWS):
            r = slice(a, a + _CHUNK_ROWS)
            writer.add(
                table.pose_id[r],
                table.t[r],
                table.leg[r],
                table.position[r],
                table.quaternion[r],
                table.readings[r],
                None if table.temperature is None else table.temperature[r],
                [table.step[r].tolist(), table.constraint[r].tolist()]
                + [table.extra[c][r].tolist() for c in names[2:]],
            )
        _attach(session, writer, out)
    except BaseException:
        writer.discard()
        raise
    return session._block_path


def remove_stale_blocks(path: Path, keep: str | None) -> list[Path]:
    """Remove the pose blocks beside the session file ``path`` that were written for a file of
    its name (``<name>.<12 hex digits>.poses.npy``) but that it no longer names (it names
    ``keep``) and no other file in the folder names either: left by a session file deleted,
    then a table imported again under its name, or by a save interrupted between its block
    and its file. The blocks removed. Call it only holding ``path``'s lock (its blocks are
    written only so). A file that cannot be read keeps every block: nothing named is lost."""
    own = re.compile(rf"{re.escape(path.name)}\.[0-9a-f]{{12}}{re.escape(SUFFIX)}")
    try:
        stale = [p for p in path.parent.iterdir() if own.fullmatch(p.name) and p.name != keep]
        if not stale:
            return []
        named = _named_in_folder(path.parent, [p.name for p in stale])
    except OSError:
        return []
    removed = []
    for block in stale:
        if block.name not in named:
            try:
                block.unlink(missing_ok=True)
            except OSError:  # left as it was: the session is not harmed by it
                continue
            removed.append(block)
    return removed


def _named_in_folder(folder: Path, names: list[str]) -> set[str]:
    """Those of ``names`` any file in ``folder`` holds (a block's own files aside), as they
    are or as JSON escapes them; the files are read a block at a time (OSError: unknown)."""
    forms = {
        name: {
            f.encode("utf-8")
            for f in (name, json.dumps(name)[1:-1], json.dumps(name, ensure_ascii=False)[1:-1])
        }
        for name in names
    }
    overlap = max(len(f) for fs in forms.values() for f in fs)
    found: set[str] = set()
    for other in folder.iterdir():
        if other.name.endswith(SUFFIX) or not other.is_file():
            continue
        with open(other, "rb") as fh:
            tail = b""
            while chunk := fh.read(_SCAN_BYTES):
                data = tail + chunk
                found |= {n for n, fs in forms.items() if any(f in data for f in fs)}
                tail = data[-overlap:]
        if len(found) == len(names):
            break
    return found
