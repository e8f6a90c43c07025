"""python-can and canopen glue for the leg encoders' driver
(:class:`~hexcal.drivers.can_encoders.LegEncoders`): the listener that hands it each frame, the
log recorder the receive thread and the senders share, and canopen's Network with a short
notifier cycle whose sent frames go to that log in the order they went on the bus."""

from __future__ import annotations

import contextlib
import copy
import threading
import time
from pathlib import Path
from typing import Any, Protocol

import can
import canopen


class FrameSink(Protocol):
    """What the listener hands frames to: the driver's receive path."""

    def _on_message(self, msg: can.Message) -> None: ...

    def _on_receive_error(self, exc: Exception) -> None: ...


class Listener(can.Listener):
    """Hands every frame python-can's notifier receives, and its receive errors, to the driver."""

    def __init__(self, owner: FrameSink):
        self.owner = owner

    def on_message_received(self, msg: can.Message) -> None:
        self.owner._on_message(msg)

    def on_error(self, exc: Exception) -> None:
        self.owner._on_receive_error(exc)

    def stop(self) -> None:
        pass


class Recorder:
    """A python-can log writer shared by the receive thread and the senders.

    ``lock`` (reentrant) is held by the receive thread across writing *and* handling a frame,
    and by the SYNC producer across opening a set, sending and writing the SYNC: so the log's
    order is the order the driver saw, and a replay assigns every position to the same SYNC."""

    def __init__(self, path: Path):
        self.path = path
        self.writer = can.Logger(str(path))
        self.lock = threading.RLock()
        self.closed = False

    def write(self, msg: can.Message) -> None:
        """Write one frame; the caller holds ``lock``."""
        if self.closed:
            return
        if not isinstance(msg.channel, (int, type(None))):
            # Virtual channel names are not channel numbers; BLF stores a 16-bit number.
            msg = copy.copy(msg)
            msg.channel = None
        self.writer.on_message_received(msg)

    def stop(self) -> None:
        with self.lock:
            if not self.closed:
                self.closed = True
                self.writer.stop()


class Network(canopen.Network):
    """canopen's Network with a shorter notifier cycle (stop() returns in ~50 ms, not 1 s) and
    every frame it sends written to the recorder, under the recorder's lock so the log keeps
    the true order (our SYNC before the answers to it)."""

    NOTIFIER_CYCLE = 0.05
    NOTIFIER_SHUTDOWN_TIMEOUT = 1.0

    def __init__(self, bus: can.BusABC | None, recorder: Recorder | None):
        super().__init__(bus)
        self.recorder = recorder

    def send_message(self, can_id: int, data: Any, remote: bool = False) -> None:
        if not self.bus:
            raise RuntimeError("Not connected to CAN bus")
        msg = can.Message(
            arbitration_id=can_id,
            data=bytes(data or b""),
            is_extended_id=can_id > 0x7FF,
            is_remote_frame=remote,
            is_rx=False,
            timestamp=time.time(),
        )
        rec = self.recorder
        with rec.lock if rec else contextlib.nullcontext(), self.send_lock:
            self.bus.send(msg)
            if rec:
                rec.write(msg)
        self.check()
