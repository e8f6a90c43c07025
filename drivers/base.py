"""What every device driver (and every mock device) shares, in python-can's habit: a device is
opened, used and closed, and is a context manager that opens it if needed and closes it on the
way out, whatever happened. Each driver supplies :meth:`Device.open`, :meth:`Device.close` and
:attr:`Device.is_open`; faults are raised as :class:`~hexcal.errors.DeviceError` (its
children name the device and what to check)."""

from __future__ import annotations

import logging
from abc import ABC, abstractmethod
from types import TracebackType
from typing import TYPE_CHECKING, Any

from hexcal.errors import DeviceError

if TYPE_CHECKING:
    import serial

try:  # a hung-up tty makes tcflush raise termios.error, which is not an OSError
    import termios

    SERIAL_IO_ERRORS: tuple[type[BaseException], ...] = (OSError, termios.error)
except ImportError:  # pragma: no cover - Windows
    SERIAL_IO_ERRORS = (OSError,)

log = logging.getLogger(__name__)


class Device(ABC):
    """A device hexcal talks to (or a mock of one): ``with device: ...`` opens it unless it is
    open already and always closes it."""

    @property
    @abstractmethod
    def is_open(self) -> bool:
        """Whether the device is open (connected, running)."""

    @abstractmethod
    def open(self) -> Any:
        """Connect and make the device ready; returns the device."""

    @abstractmethod
    def close(self) -> None:
        """Release the device; safe to call twice and on a device that never opened."""

    def __enter__(self) -> Any:
        if not self.is_open:
            self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class SerialDevice(Device):
    """A device on a pyserial port (``url`` as :func:`serial.serial_for_url` takes it): open
    while it holds a port; :meth:`_close_port` lets go of the port and never raises."""

    url: str
    port: serial.Serial | None = None

    @property
    def is_open(self) -> bool:
        return self.port is not None

    def _close_port(self) -> None:
        port, self.port = self.port, None
        if port is not None:
            try:
                port.close()
            except SERIAL_IO_ERRORS as exc:  # closing a vanished port: nothing left to do
                log.debug("closing %s: %s", self.url, exc)


__all__ = ["SERIAL_IO_ERRORS", "Device", "DeviceError", "SerialDevice"]
