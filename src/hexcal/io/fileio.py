"""Atomic writes: a crash, a full disk or a file-size limit never leaves a half-written file
where a good one was, nor a new file or folder cut short.

Every error names the user's path (never the hidden temporary file) and says what to do;
:func:`check_output` checks an output path before any work is done. Text goes through
:func:`write_text_atomic`, several files as one step through :func:`write_files_atomic`, and
what a library writes itself (a figure's PNG) through :func:`write_atomic_with`, a large file
written piece by piece (a session's pose block) through :class:`StreamedFile`;
:func:`new_folder` removes a folder it made when what was to fill it failed.
"""

from __future__ import annotations

import errno
import os
import re
import tempfile
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from hexcal.errors import HexcalError


class OutputFileError(HexcalError, OSError):
    """A file could not be written; the message names the user's path (not a temporary file)
    and says what to do. Also an :class:`OSError`, so callers that catch those still do."""

    def __init__(self, message: str, path: str | Path | None = None):
        super().__init__(message)
        self.path = None if path is None else Path(path)

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


def _why(exc: OSError, path: Path) -> str:
    """An OS error on writing ``path`` in the user's terms, with what to do."""
    folder = path.parent if str(path.parent) else Path(".")
    code = exc.errno
    if code == errno.ENOENT and not folder.is_dir():
        return f"the folder {folder} does not exist; create it, or choose another path"
    if code == errno.EISDIR or path.is_dir():
        return f"is a folder; give a file name inside it (e.g. {path / 'NAME'})"
    if code == errno.ENOTDIR:
        return f"{folder} is not a folder; choose another path"
    if code in (errno.EACCES, errno.EPERM):
        return f"no permission to write in {folder}; choose a folder you can write to"
    if code == errno.EROFS:
        return f"{folder} is on a read-only file system; choose another folder"
    if code == errno.ENOSPC:
        return "the disk is full; free some space and try again"
    if code == errno.EDQUOT:
        return "the disk quota is exceeded; free some space and try again"
    if code == errno.EFBIG:
        return (
            "the file would be larger than this process may write (its file-size limit, "
            "ulimit -f); raise the limit, or write elsewhere"
        )
    return f"cannot be written ({exc.strerror or exc}); check the path and its folder"


def write_error(exc: OSError, path: str | Path) -> OutputFileError:
    """The error for an OS error met while writing ``path``: the user's path and what to do."""
    path = Path(path)
    return OutputFileError(f"{path}: {_why(exc, path)}", path)


def check_output(path: str | Path, *, folder: bool = False, example: str = "") -> None:
    """Refuse, before any work, an output path that cannot be written: ``path`` a folder where
    a file is wanted (``folder`` False; ``example`` names a file to suggest inside it) or a file
    where a folder is wanted, a folder that does not exist (a file's folder must; an output
    folder is made if its parent exists) or one this process may not write in. Raises
    :class:`OutputFileError`. Whether an existing file may be replaced is the caller's rule."""
    path = Path(path)
    if folder:
        if path.exists() and not path.is_dir():
            raise OutputFileError(
                f"{path}: is a file, but a folder is wanted here; choose another --out", path
            )
        parent = path if path.is_dir() else path.parent
    else:
        if path.is_dir():
            name = example or "NAME"
            raise OutputFileError(
                f"{path}: is a folder; give a file name inside it (e.g. {path / name})", path
            )
        parent = path.parent
    parent = parent if str(parent) else Path(".")
    if not parent.exists():
        raise OutputFileError(
            f"{path}: the folder {parent} does not exist; create it (mkdir -p {parent}) or "
            "choose another path",
            path,
        )
    if not parent.is_dir():
        raise OutputFileError(f"{path}: {parent} is not a folder; choose another path", path)
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputFileError(
            f"{path}: no permission to write in {parent}; choose a folder you can write to", path
        )


#: write_text_atomic's temporary files: ``.<name>.<8 random characters>.tmp`` next to the file
#: (tempfile.mkstemp's random part: lower-case letters, digits, underscore).
TEMP_SUFFIX = ".tmp"
_RANDOM_PART = r"[a-z0-9_]{8}"


def _temp_prefix(path: Path) -> str:
    return f".{path.name}."


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file, fsync and rename.

    The rename is atomic on POSIX and Windows, so readers see either the old file or the new one.
    An OS error becomes :class:`OutputFileError`, naming ``path`` (not the temporary file).
    """
    path = Path(path)
    try:
        _write(path, text)
    except OutputFileError:
        raise
    except OSError as exc:
        raise write_error(exc, path) from None
    _fsync_directory(path.parent)


def _write(path: Path, text: str) -> None:
    mode = _new_mode(path)
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


def write_atomic_with(path: str | Path, write: Callable[[Path], Any]) -> None:
    """Have ``write(temporary path)`` write a file (a figure's PNG: a library that writes to a
    path itself), then fsync it and rename it to ``path``, so ``path`` is either whole or not
    there. An OS error becomes :class:`OutputFileError` naming ``path``; the temporary file
    (named as :func:`write_text_atomic` names its own) never stays."""
    path = Path(path)
    mode = _new_mode(path)
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(
            prefix=_temp_prefix(path), suffix=TEMP_SUFFIX, dir=path.parent or "."
        )
        os.close(fd)
        write(Path(tmp))
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException as exc:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError) and not isinstance(exc, OutputFileError):
            raise write_error(exc, path) from None
        raise
    _fsync_directory(path.parent)


class StreamedFile:
    """A large file written piece by piece (:attr:`fh`, binary) to a temporary file named as
    :func:`write_text_atomic` names ``owner``'s (so an interrupted write is one of
    :func:`orphan_temp_files` of ``owner``, removed when it is next opened), then fsynced and
    renamed by :meth:`publish` to a name known only at the end (a checksum in it), or removed
    by :meth:`discard`. An OS error becomes :class:`OutputFileError` naming ``owner``, the
    user's path, and the temporary file is removed."""

    def __init__(self, owner: str | Path):
        self.owner = Path(owner)
        try:
            fd, tmp = tempfile.mkstemp(
                prefix=_temp_prefix(self.owner), suffix=TEMP_SUFFIX, dir=self.owner.parent or "."
            )
        except OSError as exc:
            raise write_error(exc, self.owner) from None
        self.tmp = Path(tmp)
        self.fh: IO[bytes] = os.fdopen(fd, "w+b")

    def error(self, exc: OSError) -> OutputFileError:
        """``exc`` in the user's terms (naming ``owner``), the temporary file removed."""
        self.discard()
        return write_error(exc, self.owner)

    def publish(self, path: str | Path) -> None:
        """Flush, fsync and rename the file to ``path`` (in ``owner``'s folder)."""
        path = Path(path)
        try:
            self.fh.flush()
            os.fsync(self.fh.fileno())
            self.fh.close()
            os.chmod(self.tmp, _new_mode(path))
            os.replace(self.tmp, path)
        except OSError as exc:
            raise self.error(exc) from None
        _fsync_directory(path.parent)

    def discard(self) -> None:
        """Close and remove the temporary file (nothing is left)."""
        try:
            self.fh.close()
        except OSError:
            pass
        self.tmp.unlink(missing_ok=True)


@contextmanager
def new_folder(folder: str | Path) -> Iterator[Path]:
    """``folder``, made with its parents when missing, for the ``with`` block to fill: when the
    block fails, the folders made here are removed again if they are still empty (a failed
    export or plot set leaves no empty folder); an OS error making it names it."""
    folder = Path(folder)
    made = [p for p in reversed([folder, *folder.parents]) if not p.exists()]
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _undo([], made)
        raise write_error(exc, folder) from None
    try:
        yield folder
    except BaseException:
        _undo([], made)
        raise


def write_files_atomic(folder: str | Path, files: Mapping[str, str | Iterable[str]]) -> None:
    """Write several files into ``folder`` (made if needed, with its parents) as one step: each
    text (a str, or pieces of text written as they come: a large table) goes to a temporary
    file first, and only when all are on disk are they renamed into
    place. A name may hold ``/`` (a file in a subfolder, made as needed). A failure before the
    renames leaves nothing behind — no file, and no folder this call made — and is raised as
    :class:`OutputFileError` naming the user's path."""
    folder = Path(folder)
    made: list[Path] = []
    for parent in reversed([folder, *folder.parents]):
        if not parent.exists():
            made.append(parent)
    staged: list[tuple[str, Path]] = []
    target = folder
    try:
        folder.mkdir(parents=True, exist_ok=True)
        for name, text in files.items():
            target = folder / name
            for sub in reversed(target.parents):
                if sub.is_relative_to(folder) and sub != folder and not sub.exists():
                    sub.mkdir()
                    made.append(sub)
            fd, temp = tempfile.mkstemp(
                prefix=_temp_prefix(target), suffix=TEMP_SUFFIX, dir=target.parent
            )
            staged.append((name, Path(temp)))
            with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
                for piece in [text] if isinstance(text, str) else text:
                    fh.write(piece)
                fh.flush()
                os.fsync(fh.fileno())
            os.chmod(temp, _new_mode(target))
        for name, tmp in staged:
            target = folder / name
            os.replace(tmp, target)
    except OSError as exc:
        _undo(staged, made)
        raise write_error(exc, target) from None
    except BaseException:
        _undo(staged, made)
        raise
    _fsync_directory(folder)


def _undo(staged: list[tuple[str, Path]], made: list[Path]) -> None:
    for _, tmp in staged:
        tmp.unlink(missing_ok=True)
    for folder in reversed(made):  # the deepest first; only if still empty
        try:
            folder.rmdir()
        except OSError:
            pass


def _new_mode(path: Path) -> int:
    """The mode a written file gets: an existing file's own, else the umask's."""
    try:
        return path.stat().st_mode & 0o777
    except FileNotFoundError:
        # mkstemp makes 0600 files; an exported file should get the usual umask-derived mode.
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


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
