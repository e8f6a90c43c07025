"""A mock NDI tracker behind a real pseudo-terminal: the driver opens a device path exactly as it
opens ``/dev/ttyUSB0``.

A thread serves :class:`~hexcal.mock_hw.ndi_tracker.MockNDITracker` on the pty's master side;
:attr:`PtyTracker.device_path` is a symlink to the slave (``/dev/pts/N``) that stays the same
across :meth:`~PtyTracker.unplug` / :meth:`~PtyTracker.replug`, as a udev
``/dev/serial/by-id/...`` link does for a USB adapter plugged back in.

Linux ptys carry no BREAK (``tcsendbreak`` on a pty does nothing), so through a pty the tracker
is reset with the ``RESET`` command: open the driver with ``reset="command"`` (or ``"auto"``,
which falls back to it). The slave's baud rate is read from the pty (the master sees the slave's
termios), so a driver that forgets COMM's baud switch is caught here too. POSIX only.
"""

from __future__ import annotations

import contextlib
import os
import select
import shutil
import tempfile
import termios
import threading
import tty
from types import TracebackType

from hexcal.mock_hw.ndi_tracker import MockNDITracker

_SPEEDS = {
    getattr(termios, f"B{rate}"): rate
    for rate in (9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600)
    if hasattr(termios, f"B{rate}")
}
_POLL_S = 0.01  # longest wait of the serving loop (s): bounds unplug() and stop() latency


class PtyTracker:
    """Serve ``device`` (default: a new :class:`MockNDITracker`) on a pseudo-terminal.

    Use as a context manager, or :meth:`start` / :meth:`stop`. :meth:`unplug` closes the pty (the
    driver's next read or write fails as with a pulled cable); :meth:`replug` makes a new one
    behind the same :attr:`device_path`.
    """

    def __init__(self, device: MockNDITracker | None = None, link_name: str = "ndi-tracker"):
        self.device = device if device is not None else MockNDITracker()
        self.link_name = link_name
        self._dir: str | None = None
        self._master = -1
        self._slave = -1
        self._backlog = b""  # output the pty could not take yet
        self._fd_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def device_path(self) -> str:
        """The path to open (a stable symlink to the current pty slave)."""
        if self._dir is None:
            raise RuntimeError("PtyTracker is not started")
        return os.path.join(self._dir, self.link_name)

    @property
    def plugged(self) -> bool:
        return self._master >= 0

    def start(self) -> PtyTracker:
        if self._thread is not None:
            return self
        self._dir = tempfile.mkdtemp(prefix="hexcal-pty-")
        self._stop.clear()
        with self._fd_lock:
            self._plug_locked()
        self._thread = threading.Thread(target=self._serve, name="hexcal-pty-tracker", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving, close the pty and remove the symlink (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        with self._fd_lock:
            self._unplug_locked()
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
            self._dir = None

    def unplug(self) -> None:
        """Pull the cable: the pty closes and the device path disappears."""
        with self._fd_lock:
            self._unplug_locked()
        self.device.discard_all()

    def replug(self) -> None:
        """Plug it back in: a new pty behind the same :attr:`device_path`."""
        with self._fd_lock:
            if self._master < 0:
                self._plug_locked()

    def __enter__(self) -> PtyTracker:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    # -- internals ------------------------------------------------------------------------------------
    def _plug_locked(self) -> None:
        master, slave = os.openpty()
        # Raw from the start: a reply written before the driver configures the port must not be
        # echoed or translated by the line discipline.
        tty.setraw(slave)
        os.set_blocking(master, False)
        # The slave stays open here too, so the master does not read EIO between the driver's
        # close and its next open.
        self._master, self._slave, self._backlog = master, slave, b""
        tmp = self.device_path + ".new"
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        os.symlink(os.ttyname(slave), tmp)
        os.replace(tmp, self.device_path)  # atomic: the path never points nowhere while plugged

    def _unplug_locked(self) -> None:
        for fd in (self._master, self._slave):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = -1
        self._backlog = b""
        if self._dir is not None:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.device_path)

    def _host_baud(self, master: int) -> int | None:
        try:
            return _SPEEDS.get(termios.tcgetattr(master)[5])  # the slave's output speed
        except termios.error:
            return None

    def _serve(self) -> None:
        while not self._stop.is_set():
            with self._fd_lock:
                master = self._master
                if master >= 0:
                    self._step(master)
            if master < 0:
                self._stop.wait(_POLL_S)

    def _step(self, master: int) -> None:
        wait = self.device.next_arrival_in()
        wait = _POLL_S if wait is None or self._backlog else min(wait, _POLL_S)
        readable, _, _ = select.select([master], [], [], wait)
        if readable:
            try:
                data = os.read(master, 4096)
            except (BlockingIOError, InterruptedError):
                data = b""
            except OSError:  # no slave open: nothing to read
                data = b""
            if data:
                self.device.feed(data, host_baud=self._host_baud(master))
        out = self._backlog + self.device.pop_arrived()
        if out:
            try:
                n = os.write(master, out)
            except BlockingIOError:
                n = 0
            except OSError:  # nobody listening: the bytes are lost, as on an open line
                n = len(out)
            self._backlog = out[n:]
