"""An instant acquisition: still windows sampled straight from a :class:`MockRobot`.

No drivers, no threads, no waiting: :meth:`InstantAcquisition.record` draws a still window's
tracker samples and reading sets from the simulated robot at once, on a simulated clock, and
makes the recorded pose with the same :func:`~hexcal.acquire.acquisition.record_pose` as the real
acquisition. For what needs a calibration session fast and reproducibly — the text UI's
snapshot and unit tests, scripted checks of the guided session — and not for testing devices:
the drivers and their timing are tested against the mock devices in ``mock_hw`` (and the
text UI's whole-session Pilot test runs through them).
"""

from __future__ import annotations

from hexcal.acquire.acquisition import (
    LegSample,
    RecordedPose,
    StillWindow,
    TrackerSample,
    record_pose,
)
from hexcal.mock_hw.robot import MockRobot


class InstantAcquisition:
    """Records from ``robot`` with a window of ``window.duration_s`` simulated seconds:
    ``tracker_hz`` and ``sync_hz`` samples per second. Implements ``record()`` and ``latest()``
    as :class:`~hexcal.acquire.acquisition.Acquisition` does."""

    def __init__(
        self,
        robot: MockRobot,
        window: StillWindow | None = None,
        tracker_hz: float = 60.0,
        sync_hz: float = 100.0,
    ):
        self.robot = robot
        self.window = window or StillWindow(duration_s=0.25)
        self.tracker_hz, self.sync_hz = tracker_hz, sync_hz
        self.t = 0.0  # simulated clock, s
        self._latest: tuple[TrackerSample | None, LegSample | None] = (None, None)

    def _window(self) -> tuple[list[TrackerSample], list[LegSample], float]:
        d = self.window.duration_s
        t0 = self.t
        ts = []
        for i in range(max(1, round(d * self.tracker_hz))):
            s = self.robot.tracker_sample()
            t = t0 + (i + 0.5) / self.tracker_hz
            ts.append(
                TrackerSample(t, None, None, fault="tool 01 MISSING")
                if s is None
                else TrackerSample(t, s[0], s[1], s[2])
            )
        ls = [
            LegSample(t0 + (i + 0.5) / self.sync_hz, self.robot.encoder_readings())
            for i in range(max(1, round(d * self.sync_hz)))
        ]
        self.t = t0 + d
        self._latest = (ts[-1], ls[-1])
        return ts, ls, self.t

    def record(self) -> RecordedPose:
        """A still window from the robot as it stands (raises PoseRefused as the real one)."""
        ts, ls, t_end = self._window()
        return record_pose(ts, ls, self.window, t_end)

    def refresh(self) -> None:
        """Take one sample of each stream now (what the live display shows)."""
        s = self.robot.tracker_sample()
        self.t += 1.0 / self.tracker_hz
        trk = (
            TrackerSample(self.t, None, None, fault="tool 01 MISSING")
            if s is None
            else TrackerSample(self.t, s[0], s[1], s[2])
        )
        self._latest = (trk, LegSample(self.t, self.robot.encoder_readings()))

    def latest(self) -> tuple[TrackerSample | None, LegSample | None]:
        return self._latest


__all__ = ["InstantAcquisition"]
