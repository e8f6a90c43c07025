"""Open the configured devices as one running :class:`~hexcal.acquire.acquisition.Acquisition`.

The tracker (NDI Combined API, polled with ``BX`` for float resolution, or a line-protocol
stream) and the six CAN leg encoders are opened from a :class:`~hexcal.acquire.devices.DevicesConfig`
and read in the acquisition's threads; leaving the context stops the threads and closes the
devices, in that order, whatever happened.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from hexcal.acquire.acquisition import Acquisition, StillWindow, TrackerSample
from hexcal.acquire.devices import DevicesConfig

if TYPE_CHECKING:
    from hexcal.drivers.lineproto import LineTracker
    from hexcal.drivers.ndi import NDITracker

log = logging.getLogger(__name__)


class _BinaryPoll:
    """An NDI tracker as a PoseSource polled with BX (float32, finer than TX's text).

    A lost connection (cable or USB adapter pulled, tracker switched off) is reconnected here,
    in the acquisition's thread: every ``retry_s`` it reopens the port, resets the tracker,
    sets the tools up and resumes tracking. Until that works each sample raises
    :class:`~hexcal.drivers.ndi.TrackerDisconnected` with what to do, so the acquisition flags
    that time and a pose recorded in it is refused; the operator only plugs the cable back."""

    def __init__(self, tracker: Any, retry_s: float = 1.0):
        self.tracker = tracker
        self.retry_s = retry_s
        self._next_try = 0.0

    def sample(self) -> TrackerSample:
        from hexcal.drivers.ndi_protocol import TrackerDisconnected, TrackerError

        if self.tracker.lost:
            now = time.monotonic()
            if now < self._next_try:
                time.sleep(min(self._next_try - now, 0.05))
                raise TrackerDisconnected(self._unplugged(), self.tracker.url)
            self._next_try = now + self.retry_s
            try:
                self.tracker.reconnect()
            except TrackerError as exc:
                # The tracker can fail again half way through (reset, tools): still lost.
                self.tracker.mark_lost(exc)
                raise TrackerDisconnected(self._unplugged(), self.tracker.url) from exc
            log.warning("tracker on %s reconnected: tracking again", self.tracker.url)
        return self.tracker.sample(binary=True)

    def _unplugged(self) -> str:
        return (
            f"the tracker on {self.tracker.url} is disconnected: plug its cable or USB adapter "
            "back in on the same port (and check it is switched on); hexcal reconnects by itself"
        )


@dataclass
class LiveRig:
    """The running acquisition and the drivers behind it."""

    acquisition: Acquisition
    tracker: Any
    encoders: Any


@contextlib.contextmanager
def open_rig(cfg: DevicesConfig, window: StillWindow | None = None) -> Iterator[LiveRig]:
    """Connect the tracker, start the encoders, start acquiring; stop and close on exit."""
    from hexcal.drivers.can_encoders import LegEncoders

    with contextlib.ExitStack() as stack:
        tracker: NDITracker | LineTracker
        if cfg.tracker.kind == "ndi":
            from hexcal.drivers.ndi import NDITracker

            tracker = NDITracker(
                cfg.tracker.url,
                cfg.tracker.baudrate,
                cfg.tracker.timeout_s,
                reset=cfg.tracker.reset,
            )
            stack.enter_context(tracker)
            tracker.connect()
            source: Any = _BinaryPoll(tracker)
        else:
            from hexcal.drivers.lineproto import LineTracker

            tracker = stack.enter_context(
                LineTracker(cfg.tracker.url, cfg.tracker.baudrate, cfg.tracker.timeout_s)
            )
            source = tracker
        encoders = LegEncoders(cfg.can).start()
        stack.callback(encoders.stop)
        acq = Acquisition(source, encoders, window or cfg.still.window())
        stack.enter_context(acq)
        yield LiveRig(acq, tracker, encoders)
