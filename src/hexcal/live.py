"""Open the configured devices as one running :class:`~hexcal.acquisition.Acquisition`.

The tracker (NDI Combined API, polled with ``BX`` for float resolution, or a line-protocol
stream) and the six CAN leg encoders are opened from a :class:`~hexcal.devices.DevicesConfig`
and read in the acquisition's threads; leaving the context stops the threads and closes the
devices, in that order, whatever happened.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from hexcal.acquisition import Acquisition, StillWindow, TrackerSample
from hexcal.devices import DevicesConfig


class _BinaryPoll:
    """An NDI tracker as a PoseSource polled with BX (float32, finer than TX's text)."""

    def __init__(self, tracker: Any):
        self.tracker = tracker

    def sample(self) -> TrackerSample:
        return self.tracker.sample(binary=True)


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
