"""pyserial URL handler for ``ndimock://``: a serial port whose other end is a
:class:`~hexcal.mock_hw.ndi_tracker.MockNDITracker`.

pyserial imports this module for ``serial.serial_for_url("ndimock://...")`` once
``hexcal.mock_hw`` is in ``serial.protocol_handler_packages``, which importing
:mod:`hexcal.mock_hw.ndi_tracker` arranges. URL syntax and options: see that module.

The port behaves as a serial port does: ``read`` honours ``timeout``; ``reset_input_buffer``
discards what has arrived but not what is still in flight; ``send_break`` resets the tracker;
the baud rate set on the port is the rate the device hears (a mismatch loses the bytes); pulling
the device's cable (:meth:`MockNDITracker.unplug`) makes every operation raise
:class:`serial.SerialException`, as a vanished USB adapter does, until the port is opened again.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from serial.serialutil import PortNotOpenError, SerialException

from hexcal.mock_hw.ndi_registry import device_for_url
from hexcal.mock_hw.ndi_tracker import MockNDITracker
from hexcal.mock_hw.serial_port import MockSerialBase

if TYPE_CHECKING:
    from typing_extensions import Buffer


class Serial(MockSerialBase):
    """A pyserial port connected to a mock NDI tracker."""

    BAUDRATES = (9600, 14400, 19200, 38400, 57600, 115200, 230400, 921600, 1228739)

    def __init__(self, *args, **kwargs):
        self._device: MockNDITracker | None = None
        self._generation = -1
        super().__init__(*args, **kwargs)

    # -- open / close ---------------------------------------------------------------------------------
    def open(self) -> None:
        port = self._port_to_open()
        try:
            device = device_for_url(port)
        except (ValueError, KeyError) as exc:
            raise SerialException(f"could not open port {self.portstr}: {exc.args[0]}") from None
        if not device.plugged:
            raise SerialException(
                f"could not open port {self.portstr}: no such device (the cable is unplugged)"
            )
        self._device = device
        self._generation = device.generation
        self._reconfigure_port()
        self.is_open = True
        device.discard_input()

    def close(self) -> None:
        self.is_open = False
        self._device = None
        super().close()

    def _live(self) -> MockNDITracker:
        if not self.is_open or self._device is None:
            raise PortNotOpenError()
        dev = self._device
        if not dev.plugged or dev.generation != self._generation:
            raise SerialException(f"device {self.portstr} disconnected (cable unplugged)")
        return dev

    # -- data -----------------------------------------------------------------------------------------
    @property
    def in_waiting(self) -> int:
        return self._live().in_waiting()

    def read(self, size: int = 1) -> bytes:
        dev = self._live()
        timeout = self.timeout
        deadline = None if timeout is None else time.monotonic() + timeout
        data = bytearray()
        while len(data) < size:
            remaining = None if deadline is None else max(deadline - time.monotonic(), 0.0)
            chunk = dev.read(size - len(data), remaining, self._generation)
            if chunk is None:
                raise SerialException(f"device {self.portstr} disconnected (cable unplugged)")
            data += chunk
            if not chunk:  # timed out
                break
        return bytes(data)

    def write(self, data: Buffer) -> int:
        dev = self._live()
        data = bytes(data)
        dev.feed(data, host_baud=self.baudrate)
        return len(data)

    def reset_input_buffer(self) -> None:
        self._live().discard_input()

    def reset_output_buffer(self) -> None:
        self._live()  # writes are delivered at once: nothing waits to go out

    @property
    def out_waiting(self) -> int:
        self._live()
        return 0

    # -- modem lines and break (the lines: MockSerialBase) --------------------------------------
    def _line_check(self) -> None:
        self._live()

    def _update_break_state(self) -> None:
        if self.break_condition:  # the tracker resets on the BREAK's start
            self._live().on_break()
