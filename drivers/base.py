"""What every device driver (and every mock device) shares, in python-can's habit: a device is
opened, used and closed, and is a context manager that opens it if needed and closes it on the
way out, whatever happened. Each driver supplies :meth:`Device.open`, :meth:`Device.close` and
:attr:`Device.is_open`; faults are raised as :class:`~hexcal.errors.DeviceError` (its
children name the device and what to check)."""

from __future__ import annotations

from abc import ABC, abstractmethod
from types import TracebackType
from typing import Any

from hexcal.errors import DeviceError


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


__all__ = ["Device", "DeviceError"]
