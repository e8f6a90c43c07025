"""What the mock trackers' pyserial URL handlers (``ndimock://``, ``ndireplay://``) share: the
baud-rate check of a real port, and modem lines that are always ready (a tracker's USB adapter
raises CTS, DSR and CD). Each handler says through :meth:`MockSerialBase._line_check` whether
its line is there, so the lines fail as the data calls do on a closed or unplugged port."""

from __future__ import annotations

import numbers

from serial.serialutil import PortNotOpenError, SerialBase, SerialException


class MockSerialBase(SerialBase):
    """A pyserial port with no hardware behind it; subclasses supply the data calls."""

    def _port_to_open(self) -> str:
        """The port name :meth:`open` connects to; refuses, as pyserial does, a port that is
        open already or has no name."""
        if self.is_open:
            raise SerialException("Port is already open.")
        if self.portstr is None:
            raise SerialException("Port must be configured before it can be used.")
        return self.portstr

    def _line_check(self) -> None:
        """Raise as pyserial would when the line is not there (closed port by default)."""
        if not self.is_open:
            raise PortNotOpenError()

    def _reconfigure_port(self) -> None:
        baud: object = self.baudrate  # as set: pyserial's setter lets a float through
        if not isinstance(baud, numbers.Integral) or not 0 < int(baud) < 2**32:
            raise ValueError(f"invalid baudrate: {baud!r}")

    # -- modem lines and break (no line: accepted and ignored) ----------------------------------
    def _update_break_state(self) -> None:
        self._line_check()

    def _update_rts_state(self) -> None:
        pass

    def _update_dtr_state(self) -> None:
        pass

    @property
    def cts(self) -> bool:
        self._line_check()
        return True

    @property
    def dsr(self) -> bool:
        self._line_check()
        return True

    @property
    def ri(self) -> bool:
        self._line_check()
        return False

    @property
    def cd(self) -> bool:
        self._line_check()
        return True
