"""The pose block: a table of poses as one binary file of fixed-size records, written piece by
piece and read back whole (docs/formats.md, "The pose block").

A session that holds an imported table keeps its poses here, beside the session file, instead
of as JSON objects: 137 bytes a pose (a CSV row is about 170), read and written a block of
rows at a time, so ``session import`` streams and every command reads a 2-million-pose session
in a few hundred MB. The file is a NumPy ``.npy`` file (format 1.0, a structured dtype, no
object field, so ``np.load(path, allow_pickle=False)`` opens it too) whose header is padded to
:data:`HEADER_BYTES`, so that it can be written last, once the count is known.

Each record: ``pose_id`` int64, ``t`` float64 s, ``leg`` int8, ``position`` (3,) float64 mm,
``quaternion`` (4,) float64 scalar first, ``readings`` (6,) float64 mm, ``temperature`` float64
degC (NaN: none), ``texts`` (K,) uint32: the codes of the text columns (``step``,
``constraint``, then the extra columns), each an index into that column's list of distinct
values, which the session file holds (:class:`BlockInfo`). The session file also holds the
count and the SHA-256 of the records (the bytes after the header): a block that is short,
long, of another layout, or whose bytes changed is refused, naming it, and never overwritten.
"""

from __future__ import annotations

import ast
import hashlib
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hexcal.errors import InputError
from hexcal.io.fileio import StreamedFile

#: The ``.npy`` header's size, bytes (a multiple of 64, as NumPy aligns it): written last.
HEADER_BYTES = 1024
_MAGIC = b"\x93NUMPY\x01\x00"
#: The pose block's name: the session file's, this, and the first characters of its checksum.
SUFFIX = ".poses.npy"
#: Bytes hashed and read at a time.
_CHUNK = 1 << 22


class PoseBlockError(InputError):
    """A pose block cannot be read: the message names the file and says what to do."""


def block_dtype(texts: int) -> np.dtype:
    """The record of a pose with ``texts`` text columns (step, constraint, extras)."""
    return np.dtype(
        [
            ("pose_id", "<i8"),
            ("t", "<f8"),
            ("leg", "i1"),
            ("position", "<f8", (3,)),
            ("quaternion", "<f8", (4,)),
            ("readings", "<f8", (6,)),
            ("temperature", "<f8"),
            ("texts", "<u4", (texts,)),
        ]
    )


def _header(dtype: np.dtype, n: int) -> bytes:
    descr = np.lib.format.dtype_to_descr(dtype)
    text = repr({"descr": descr, "fortran_order": False, "shape": (n,)}).encode("latin1")
    room = HEADER_BYTES - len(_MAGIC) - 2 - 1
    if len(text) > room:
        raise ValueError(f"a pose block's header needs {len(text)} bytes, more than {room}")
    return _MAGIC + (HEADER_BYTES - 10).to_bytes(2, "little") + text.ljust(room) + b"\n"


@dataclass
class BlockInfo:
    """A written block: its file name, pose count, the SHA-256 of its records (hex) and each
    text column's distinct values in code order (``step``, ``constraint``, the extras)."""

    name: str
    poses: int
    sha256: str
    texts: dict[str, list[str]] = field(default_factory=dict)


class PoseBlockWriter:
    """Writes a pose block beside ``owner`` (the session file) a group of rows at a time.

    Rows are held only as long as :meth:`add` runs: memory does not grow with the table, but
    for the distinct texts (a few dozen step names in a lab's table). More than ``max_poses``
    rows are refused as they arrive (``too_many()`` is raised, the temporary file removed), so
    nothing a reader would refuse is ever kept. A failure anywhere leaves nothing behind
    (:class:`~hexcal.io.fileio.StreamedFile`)."""

    def __init__(
        self,
        owner: Path,
        text_columns: Sequence[str],
        max_poses: int,
        too_many: Callable[[], Exception],
    ):
        self.owner = owner
        self.columns = list(text_columns)
        self.dtype = block_dtype(len(self.columns))
        self.max_poses = max_poses
        self.too_many = too_many
        self.count = 0
        self.codes: list[dict[str, int]] = [{} for _ in self.columns]
        self.hash = hashlib.sha256()
        self.out = StreamedFile(owner)
        self._write(bytes(HEADER_BYTES))  # the real header once the count is known

    def _write(self, data: bytes | memoryview) -> None:
        try:
            self.out.fh.write(data)
        except OSError as exc:
            raise self.out.error(exc) from None

    def add(
        self,
        pose_id: np.ndarray,
        t: np.ndarray,
        leg: np.ndarray,
        position: np.ndarray,
        quaternion: np.ndarray,
        readings: np.ndarray,
        temperature: np.ndarray | None,
        texts: Sequence[Sequence[str]],
    ) -> None:
        """Append k rows: (k,) ids, times s, legs; (k, 3) mm, (k, 4), (k, 6) mm; (k,) degC or
        None; one (k,) sequence of str per text column."""
        k = len(pose_id)
        if self.count + k > self.max_poses:
            self.out.discard()
            raise self.too_many()
        rec = np.empty(k, self.dtype)
        rec["pose_id"], rec["t"], rec["leg"] = pose_id, t, leg
        rec["position"], rec["quaternion"], rec["readings"] = position, quaternion, readings
        rec["temperature"] = np.nan if temperature is None else temperature
        for j, col in enumerate(texts):
            codes = self.codes[j]
            rec["texts"][:, j] = [codes.setdefault(v, len(codes)) for v in col]
        data = rec.view(np.uint8).data
        self.hash.update(data)
        self._write(data)
        self.count += k

    def finish(self) -> BlockInfo:
        """Write the header, fsync and give the file its name (``<owner>.<sha>.poses.npy``)."""
        try:
            self.out.fh.seek(0)
            self.out.fh.write(_header(self.dtype, self.count))
        except OSError as exc:
            raise self.out.error(exc) from None
        sha = self.hash.hexdigest()
        name = f"{self.owner.name}.{sha[:12]}{SUFFIX}"
        self.out.publish(self.owner.with_name(name))
        texts = {c: list(codes) for c, codes in zip(self.columns, self.codes, strict=True)}
        return BlockInfo(name, self.count, sha, texts)

    def discard(self) -> None:
        self.out.discard()


def _damaged(path: Path, why: str) -> PoseBlockError:
    return PoseBlockError(
        f"{path}: {why}; the session's poses cannot be read from it. It is left untouched: "
        "restore it from a copy, or import the table again into a new session"
    )


def read_block(path: Path, poses: int, sha256: str, texts: int) -> np.ndarray:
    """The (poses,) records of the block at ``path``, checked: its header (a ``.npy`` 1.0 of
    the pose record with ``texts`` text columns, ``poses`` long), its size (neither cut short
    nor longer) and the SHA-256 of its records. Memory: the records, once (137 bytes a pose
    and 4 per extra column)."""
    dtype = block_dtype(texts)
    try:
        with open(path, "rb") as fh:
            head = fh.read(HEADER_BYTES)
            _check_header(path, head, dtype, poses)
            size = os.fstat(fh.fileno()).st_size
            want = HEADER_BYTES + poses * dtype.itemsize
            if size != want:
                how = "cut short" if size < want else "longer than its poses"
                raise _damaged(path, f"{how} ({size:,} bytes; {poses:,} poses take {want:,})")
            records = np.empty(poses, dtype)
            view = records.view(np.uint8).data
            digest = hashlib.sha256()
            at = 0
            while at < len(view):
                got = fh.readinto(view[at : at + _CHUNK])
                if not got:
                    raise _damaged(path, "cut short while it was read")
                digest.update(view[at : at + got])
                at += got
    except FileNotFoundError:
        raise PoseBlockError(
            f"{path}: missing; the session file keeps its poses in this file beside it. Copy "
            "or move a session file together with its .poses.npy file"
        ) from None
    except OSError as exc:
        raise PoseBlockError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if digest.hexdigest() != sha256:
        raise _damaged(path, "its bytes do not match the checksum the session file holds")
    return records


def _check_header(path: Path, head: bytes, dtype: np.dtype, poses: int) -> None:
    if len(head) < HEADER_BYTES or not head.startswith(_MAGIC):
        raise _damaged(path, "not a pose block (no NumPy 1.0 header)")
    # The records start after HEADER_BYTES here; NumPy starts them where the header says.
    if int.from_bytes(head[8:10], "little") != HEADER_BYTES - 10:
        raise _damaged(path, f"its header does not give its length as {HEADER_BYTES - 10} bytes")
    try:
        meta = ast.literal_eval(head[10:].decode("latin1").strip())
        found = np.dtype(np.lib.format.descr_to_dtype(meta["descr"]))
        shape, fortran = meta["shape"], meta["fortran_order"]
    except (ValueError, SyntaxError, KeyError, TypeError, UnicodeDecodeError):
        raise _damaged(path, "its header is not readable") from None
    if found != dtype or fortran:
        raise _damaged(path, f"its records are {found}, not the pose record {dtype}")
    if shape != (poses,):
        raise _damaged(path, f"it holds {shape} poses where the session file says {poses:,}")


def decode_texts(path: Path, codes: np.ndarray, values: Sequence[str], column: str) -> np.ndarray:
    """A text column, (N,) object array of str, from its (N,) codes and distinct values; a
    code beyond them is refused as damage."""
    table = np.empty(len(values), object)
    table[:] = list(values)
    if len(codes) and (not len(values) or int(codes.max()) >= len(values)):
        raise _damaged(path, f"a code of column '{column}' has no value in the session file")
    return table[codes]
