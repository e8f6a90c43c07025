"""Atomic text writes: a crash never leaves a half-written file where a good one was."""

from __future__ import annotations

import os
import re
import tempfile
from pathlib import Path

#: write_text_atomic's temporary files: ``.<name>.<8 random characters>.tmp`` next to the file
#: (tempfile.mkstemp's random part: lower-case letters, digits, underscore).
TEMP_SUFFIX = ".tmp"
_RANDOM_PART = r"[a-z0-9_]{8}"


def _temp_prefix(path: Path) -> str:
    return f".{path.name}."


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file, fsync and rename.

    The rename is atomic on POSIX and Windows, so readers see either the old file or the new one.
    """
    path = Path(path)
    try:
        mode = path.stat().st_mode & 0o777
    except FileNotFoundError:
        # mkstemp makes 0600 files; an exported file should get the usual umask-derived mode.
        umask = os.umask(0)
        os.umask(umask)
        mode = 0o666 & ~umask
    fd, tmp = tempfile.mkstemp(
        prefix=_temp_prefix(path), suffix=TEMP_SUFFIX, dir=path.parent or "."
    )
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    _fsync_directory(path.parent)


def _fsync_directory(directory: Path) -> None:
    """Make the rename itself durable (POSIX); a no-op where directories cannot be opened."""
    try:
        fd = os.open(directory if str(directory) else ".", os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # some filesystems refuse fsync on a directory; the rename is still atomic
    finally:
        os.close(fd)


def orphan_temp_files(path: str | Path) -> list[Path]:
    """The temporary files :func:`write_text_atomic` made for ``path`` and never renamed (a
    kill or a power cut during a save): regular files named exactly as it names them, in the
    same folder. Nothing else matches: not another file's, not a user's ``*.tmp``."""
    path = Path(path)
    pattern = re.compile(re.escape(_temp_prefix(path)) + _RANDOM_PART + re.escape(TEMP_SUFFIX))
    folder = path.parent if str(path.parent) else Path(".")
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return []
    return sorted(
        Path(e.path)
        for e in entries
        if pattern.fullmatch(e.name) and e.is_file(follow_symlinks=False)
    )


def remove_orphan_temp_files(path: str | Path) -> list[tuple[Path, int]]:
    """Delete :func:`orphan_temp_files` of ``path``; the files removed with their sizes in
    bytes. Call it only when this process owns ``path`` (a file is edited by one hexcal at a
    time, or saves would overwrite each other anyway): a save in progress elsewhere would
    lose its temporary file."""
    removed = []
    for tmp in orphan_temp_files(path):
        try:
            size = tmp.stat(follow_symlinks=False).st_size
            tmp.unlink()
        except OSError:
            continue  # gone already, or not ours to delete (permissions): leave it
        removed.append((tmp, size))
    return removed
