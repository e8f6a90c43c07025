"""One writer per session file: an advisory lock held while a process has the session open for
writing, naming its holder.

The lock is the kernel's advisory lock (``fcntl.flock`` on POSIX, ``msvcrt.locking`` on
Windows) on a small file beside the session, ``.NAME.lock``, which holds who took it: the
process id, the host, the program and when (UTC), so that a second opener is refused with
those named. The kernel drops the lock when its process ends, however it ends; a lock file
whose lock is free again was left by a process that crashed (or was killed) and is taken over,
which the new holder is told. A holder that closes the session removes the file while it still
holds the lock, and an opener checks, once it holds the lock, that the file it locked is still
the one on disk (else it opens the new one): two openers can never both hold a lock.

Why not the ``filelock`` package: it truncates the lock file when it opens it, before it knows
whether it may take the lock, so a refused opener would erase the holder it is meant to name.
"""

from __future__ import annotations

import json
import os
import socket
import sys
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from hexcal import __version__
from hexcal.errors import InputError

#: The most bytes of holder information read from a lock file (it holds about 200).
_MAX_INFO = 4096


def lock_path(session: str | Path) -> Path:
    """The lock file of a session file: ``.NAME.lock`` in the same folder."""
    session = Path(session)
    return session.with_name(f".{session.name}.lock")


@dataclass(frozen=True)
class LockHolder:
    """Who holds (or held) a session's lock: process id, host name, program, since (UTC)."""

    pid: int
    host: str
    since: str
    program: str = "hexcal"
    hexcal_version: str = ""

    @classmethod
    def me(cls) -> LockHolder:
        program = " ".join(Path(a).name if i == 0 else a for i, a in enumerate(sys.argv[:3]))
        return cls(
            pid=os.getpid(),
            host=socket.gethostname(),
            since=datetime.now(timezone.utc).isoformat(timespec="seconds"),
            program=program[:120] or "hexcal",
            hexcal_version=__version__,
        )

    @classmethod
    def parse(cls, raw: bytes) -> LockHolder | None:
        """The holder a lock file names, None when it names none (empty, damaged)."""
        try:
            data: Any = json.loads(raw.decode("utf-8"))
            return cls(
                pid=int(data["pid"]),
                host=str(data["host"])[:200],
                since=str(data["since"])[:40],
                program=str(data.get("program", "hexcal"))[:120],
                hexcal_version=str(data.get("hexcal_version", ""))[:40],
            )
        except (ValueError, KeyError, TypeError, UnicodeDecodeError):
            return None

    def text(self) -> str:
        """``process 4711 (hexcal run) on host lab-pc since 2026-11-24T17:03:00+00:00``"""
        here = "this process" if self.is_me() else f"process {self.pid}"
        return f"{here} ({self.program}) on host {self.host} since {self.since}"

    def is_me(self) -> bool:
        return self.pid == os.getpid() and self.host == socket.gethostname()

    def to_bytes(self) -> bytes:
        return (json.dumps(self.__dict__, ensure_ascii=False) + "\n").encode("utf-8")


class SessionLocked(InputError):
    """The session file is open for writing elsewhere; the message names the holder."""

    def __init__(self, message: str, holder: LockHolder | None):
        super().__init__(message)
        self.holder = holder


def _try_lock(fd: int) -> bool:
    """Take the advisory lock on the open lock file without waiting; False if it is held."""
    if sys.platform == "win32":  # pragma: no cover - exercised on Windows only
        import msvcrt

        # One byte far beyond the holder's text: a locked range cannot be read on Windows.
        os.lseek(fd, 1 << 30, os.SEEK_SET)
        try:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
        except OSError:
            return False
        return True
    import fcntl

    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


def _unlock(fd: int) -> None:
    if sys.platform == "win32":  # pragma: no cover - exercised on Windows only
        import msvcrt

        os.lseek(fd, 1 << 30, os.SEEK_SET)
        msvcrt.locking(fd, msvcrt.LK_UNLCK, 1)
        return
    import fcntl

    fcntl.flock(fd, fcntl.LOCK_UN)


def _read_info(fd: int) -> bytes:
    os.lseek(fd, 0, os.SEEK_SET)
    return os.read(fd, _MAX_INFO)


#: How long a refused opener waits for a holder that has just taken the lock to write its name.
_NAME_WAIT_S = 1.0


def _holder(fd: int) -> LockHolder | None:
    """The holder a held lock file names. A holder writes its name just after it takes the
    lock, so an opener refused in between waits a moment for it."""
    deadline = time.monotonic() + _NAME_WAIT_S
    while True:
        holder = LockHolder.parse(_read_info(fd))
        if holder is not None or time.monotonic() > deadline:
            return holder
        time.sleep(0.01)


def _same_file(fd: int, path: Path) -> bool:
    """Whether the open lock file is still the one at ``path`` (a closing holder may have
    removed it between our open and our lock)."""
    try:
        return os.fstat(fd).st_ino == path.stat().st_ino
    except OSError:
        return False


class SessionLock:
    """The lock of one session file, held from :meth:`acquire` until :meth:`release`.

    ``taken_over`` names the holder of a stale lock this one replaced (a crashed process), or
    is None."""

    def __init__(self, session: Path, fd: int, taken_over: LockHolder | None):
        self.session = session
        self.path = lock_path(session)
        self._fd: int | None = fd
        self.taken_over = taken_over

    @classmethod
    def acquire(cls, session: str | Path) -> SessionLock:
        """Take the lock of ``session`` or raise :class:`SessionLocked` naming its holder.

        An OS error (a folder one may not write in) propagates as :class:`OSError`."""
        session = Path(session)
        path = lock_path(session)
        while True:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
            if not _try_lock(fd):
                holder = _holder(fd)
                os.close(fd)
                raise SessionLocked(_locked_message(session, holder), holder)
            if _same_file(fd, path):
                break
            os.close(fd)  # removed by a holder closing meanwhile: lock the file now there
        previous = LockHolder.parse(_read_info(fd))
        try:
            os.ftruncate(fd, 0)
            os.lseek(fd, 0, os.SEEK_SET)
            os.write(fd, LockHolder.me().to_bytes())
            os.fsync(fd)
        except OSError:  # a full disk: the lock file is ours, and must not stay behind
            if _same_file(fd, path):
                path.unlink(missing_ok=True)
            _unlock(fd)
            os.close(fd)
            raise
        return cls(session, fd, previous)

    @property
    def held(self) -> bool:
        return self._fd is not None

    def release(self) -> None:
        """Give the lock up and remove its file (a no-op once released)."""
        fd, self._fd = self._fd, None
        if fd is None:
            return
        try:
            if _same_file(fd, self.path):
                # Removed while still held: an opener that opened it meanwhile sees, once it
                # holds the lock, that the file is gone, and starts again.
                self.path.unlink(missing_ok=True)
            _unlock(fd)
        except OSError:
            pass  # the kernel drops the lock with the descriptor anyway
        finally:
            os.close(fd)


def _locked_message(session: Path, holder: LockHolder | None) -> str:
    who = holder.text() if holder is not None else "another process (it left no name)"
    if holder is not None and holder.is_me():
        return (
            f"{session}: already open for writing in this program ({holder.program}, since "
            f"{holder.since}); use that window, or close it first"
        )
    return (
        f"{session}: open for writing in {who}. Two writers would lose each other's work, so "
        "it is not opened here: close it there first, or open it read-only (hexcal calibrate, "
        "diagnose and session export only read it)"
    )


def stale_notice(session: Path, holder: LockHolder) -> str:
    """What taking over a crashed holder's lock is told as."""
    return (
        f"{session}: took over the lock of {holder.text()}, which no longer holds it (it "
        "ended without closing the session); the file holds its last complete save"
    )
