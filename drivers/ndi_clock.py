"""The frame clock: the host time at which each tracker frame was measured, fitted from the
frame numbers the polls return and the times the commands were written (``docs/ndi.md``,
"Timing: the frame clock"). :mod:`hexcal.drivers.ndi` re-exports :class:`FrameClock` and
:class:`FrameTime`."""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

# The driver's logger: its warnings were always logged as hexcal.drivers.ndi's, and operators
# and tests select them by that name.
log = logging.getLogger("hexcal.drivers.ndi")


@dataclass(frozen=True, slots=True)
class FrameTime:
    """When a frame was measured: ``t`` (host monotonic s), ``uncertainty_s`` (half-width of the
    interval it lies in, s) and ``locked`` (True: from the fitted frame clock; False: from the
    poll that first returned the frame alone). NaN when nothing is known."""

    t: float
    uncertainty_s: float
    locked: bool


class FrameClock:
    """The host time (``time.monotonic()``, s) at which each tracker frame was measured, from the
    frame numbers polls return.

    A tracker measures frame n at its own fixed rate and answers a poll with the newest frame it
    has. The host cannot see when the tracker acted on a poll, only that it was within
    ``[t_lo, t_hi]`` (:meth:`observe`; the driver derives them from the command's write time and
    its transfer time, see :class:`NDITracker`). So frame n existed at ``t_hi`` (an *upper*
    point: t(n) <= t_hi) and frame n + 1 did not yet exist at ``t_lo`` (a *lower* point:
    t(n + 1) > t_lo). Frames come at a fixed period T, t(n) = t_ref + (n - n_ref) T, and the
    points of many frames pin that line down far better than any one poll does. Over the last
    ``window_s``:

    - the periods consistent with every point form an interval (the lines that pass above
      every lower point and below every upper point; only the two convex hulls matter). The
      configured ``frame_rate_hz``, known to ``drift_ppm`` (the tracker's and the host's
      crystals), narrows it while the two agree. With ``fit_rate``, the points alone decide
      once they rule the configured rate out (a tracker clock drifting against the host's, or
      a wrong setting); without it, that is a contradiction;
    - the newest frame's time lies between the lowest and the highest value any consistent line
      gives it: the tightest consistent interval. Its midpoint is the estimate; its half-width
      plus ``tolerance_s`` the uncertainty. Other frames follow the line through it with the
      best period (the one closest on average to the lower points, which are hard bounds —
      Moon, Skelly and Towsley's linear-programming clock skew estimate, upside down), their
      uncertainty growing with their distance by the spread of consistent periods.

    An upper point that no line through the lower points can pass above contradicts them: the
    tracker acted later than the bounds allow. A few (up to ``max_contradictions`` of the upper
    points) are dropped; more, or fewer than ``min_frames`` frames, or a configured rate the
    points rule out without ``fit_rate``, and the clock is not trusted: :meth:`time_of` falls
    back to the frame's own interval — from the previous poll, which returned an older frame,
    to the reply that first carried this one — and its larger half-width. The first
    contradiction is logged, and so is a fitted rate further than ``rate_tolerance``
    (relative) from ``frame_rate_hz``. A frame counter that goes back (the tracker was reset,
    or the 32-bit counter wrapped) or leaps further than the elapsed time allows restarts the
    clock.
    """

    def __init__(
        self,
        frame_rate_hz: float = 60.0,
        *,
        fit_rate: bool = True,
        drift_ppm: float = 200.0,
        window_s: float = 30.0,
        max_frames: int = 4096,
        min_frames: int = 30,
        rebuild_every: int = 15,
        rate_tolerance: float = 0.01,
        max_contradictions: float = 0.02,
        tolerance_s: float = 1e-4,
        name: str = "the tracker",
    ):
        if not (math.isfinite(frame_rate_hz) and frame_rate_hz > 0):
            raise ValueError(f"frame_rate_hz must be a positive number of Hz, not {frame_rate_hz}")
        self.frame_rate_hz = float(frame_rate_hz)
        self.fit_rate = fit_rate
        self.drift_ppm = float(drift_ppm)
        self.window_s = float(window_s)
        self.max_frames = int(max_frames)
        self.min_frames = int(min_frames)
        self.rebuild_every = int(rebuild_every)
        self.rate_tolerance = float(rate_tolerance)
        self.max_contradictions = float(max_contradictions)
        self.tolerance_s = float(tolerance_s)
        self.name = name
        #: How many times the clock restarted (frame counter went back or leapt).
        self.resets = 0
        #: Upper points dropped as contradicting the lower ones (the tracker acted late).
        self.dropped = 0
        self._warned_rate = False
        self._warned_inconsistent = False
        self.reset()
        self.resets = 0

    def reset(self, why: str = "") -> None:
        """Forget everything (a new tracker session, or its frame counter restarted)."""
        if why:
            log.info("frame clock of %s restarted: %s", self.name, why)
        self.resets += 1
        self._lo: deque[tuple[int, float]] = deque()  # (frame k, t): t(k) > t
        self._hi: deque[tuple[int, float]] = deque()  # (frame k, t): t(k) <= t
        self._own: deque[tuple[int, float, float]] = deque(maxlen=256)  # (k, lo, hi) per frame
        self._last: tuple[int, float] | None = None  # (frame, t_lo) of the last poll
        # Hull vertices (absolute frame, t) as of the last refresh: the upper hull of the lower
        # points and the lower hull of the upper points; rebuilt from every point now and then
        # (points leave the window), extended with the new points in between.
        self._lo_hull: list[tuple[int, float]] = []
        self._hi_hull: list[tuple[int, float]] = []
        self._new_frames = self.rebuild_every  # frames since the last rebuild
        self._dirty = True
        self._state = "warming up"
        # The line: n_ref, t_ref (s), period (s), half-width (s), period spread (s).
        self._line: tuple[int, float, float, float, float] | None = None
        self._fitted = False

    # -- input ------------------------------------------------------------------------------------
    def observe(self, frame: int, t_lo: float, t_hi: float, t_recv: float) -> bool:
        """One poll: the tracker acted on it at some host time in ``[t_lo, t_hi]`` (s) and
        returned ``frame`` as its newest; the reply's last byte came at ``t_recv`` (s, >=
        ``t_hi``). Returns True when ``frame`` is new (not returned by an earlier poll)."""
        if self._last is not None:
            last_frame, last_lo = self._last
            # The most frames that can have come since the last poll acted: twice the rate.
            most = 2.0 * self.frame_rate_hz * max(t_recv - last_lo, 0.0) + 10
            if frame < last_frame:
                self.reset(f"its frame counter went back from {last_frame} to {frame}")
            elif frame - last_frame > most:
                self.reset(f"its frame counter leapt from {last_frame} to {frame}")
        new = self._last is None or frame > self._last[0]
        if new:
            # The poll before returned an older frame: this one was measured after that poll
            # reached the tracker. With no poll before, the newest frame is < one period old.
            lower = self._last[1] if self._last is not None else t_lo - 1.0 / self.frame_rate_hz
            self._own.append((frame, lower, t_recv))
            self._hi.append((frame, t_hi))
            self._new_frames += 1
        if self._lo and self._lo[-1][0] == frame + 1:
            self._lo[-1] = (frame + 1, max(self._lo[-1][1], t_lo))  # the latest poll is tighter
        else:
            self._lo.append((frame + 1, t_lo))
        self._last = (frame, t_lo)
        for points in (self._lo, self._hi):
            while points and (points[0][1] < t_lo - self.window_s or len(points) > self.max_frames):
                points.popleft()
        # A repeated frame only tightens the next frame's lower point: the fit can wait for
        # that frame (polls come several times per frame; each refresh costs).
        self._dirty = self._dirty or new
        return new

    # -- output -----------------------------------------------------------------------------------
    def time_of(self, frame: int) -> FrameTime:
        """When ``frame`` was measured (host monotonic s) and how well that is known."""
        self._refresh()
        if self._line is not None:
            n_ref, t_ref, period, half, spread = self._line
            return FrameTime(
                t_ref + (frame - n_ref) * period, half + spread * abs(frame - n_ref), True
            )
        for k, lo, hi in reversed(self._own):
            if k == frame:
                return FrameTime(0.5 * (lo + hi), 0.5 * (hi - lo), False)
        return FrameTime(math.nan, math.nan, False)

    @property
    def state(self) -> str:
        """``"warming up"`` (too few frames), ``"locked"`` or ``"inconsistent"``."""
        self._refresh()
        return self._state

    def stats(self) -> dict[str, float | int | str | bool]:
        """The clock now: ``state``, ``frames`` (in the window), ``span_s`` (of the window),
        ``uncertainty_s`` (s: half-width of the interval of the newest frame's time when
        locked, else that of its own poll interval), ``frame_rate_hz`` (the rate in use),
        ``rate_fitted`` (the points, not the configured rate, decide it), ``rate_offset_ppm``
        (that rate against ``frame_rate_hz``, by the host clock), ``rate_uncertainty_ppm``
        (how far the consistent rates reach from it), ``dropped`` (upper points dropped as
        contradictions), ``resets``."""
        self._refresh()
        if self._line is not None:
            unc, period = self._line[3], self._line[2]
            spread_ppm = self._line[4] / period * 1e6
        else:
            unc = 0.5 * (self._own[-1][2] - self._own[-1][1]) if self._own else math.nan
            period, spread_ppm = 1.0 / self.frame_rate_hz, math.nan
        rate = 1.0 / period
        return {
            "state": self._state,
            "frames": len(self._hi),
            "span_s": self._lo[-1][1] - self._lo[0][1] if self._lo else 0.0,
            "uncertainty_s": unc,
            "frame_rate_hz": rate,
            "rate_fitted": self._fitted,
            "rate_offset_ppm": (rate / self.frame_rate_hz - 1.0) * 1e6,
            "rate_uncertainty_ppm": spread_ppm,
            "dropped": self.dropped,
            "resets": self.resets,
        }

    # -- the fit ----------------------------------------------------------------------------------
    def _refresh(self) -> None:
        if not self._dirty:
            return
        self._dirty = False
        self._line = None
        self._fitted = False
        if min(len(self._lo), len(self._hi)) < self.min_frames:
            self._state = "warming up"
            return
        self._update_hulls()
        # Relative to the newest frame: frame numbers reach 2**32 and host times 1e6 s, while
        # the line must be right to 1e-5 s.
        n_ref, t_ref = self._hi[-1]
        lx, ly = _relative(self._lo_hull, n_ref, t_ref)
        ux, uy = _relative(self._hi_hull, n_ref, t_ref)
        tol = self.tolerance_s
        consistent = _period_range(lx, ly, ux, uy, tol)
        if consistent is None and self._drop_contradictions(n_ref, t_ref):
            lx, ly = _relative(self._lo_hull, n_ref, t_ref)
            ux, uy = _relative(self._hi_hull, n_ref, t_ref)
            consistent = _period_range(lx, ly, ux, uy, tol)
        nominal = 1.0 / self.frame_rate_hz
        prior = (nominal * (1 - self.drift_ppm * 1e-6), nominal * (1 + self.drift_ppm * 1e-6))
        if consistent is None:
            self._inconsistent(f"no frame period fits every poll of the last {self.window_s:g} s")
            return
        both = (max(consistent[0], prior[0]), min(consistent[1], prior[1]))
        if both[0] <= both[1]:
            periods = both
            self._fitted = both != prior
        elif self.fit_rate:
            periods = consistent
            self._fitted = True
        else:
            self._inconsistent(
                f"the polls need a frame rate of {1 / consistent[1]:.6g} to "
                f"{1 / consistent[0]:.6g} Hz"
            )
            return
        if not (math.isfinite(periods[0]) and math.isfinite(periods[1])):
            self._state = "warming up"  # too short a span to bound the rate yet
            return
        low = _lowest_max(lx, ly, periods)  # the earliest time a consistent line gives frame 0
        high = _highest_min(ux, uy, periods)  # the latest
        best = min(max(_upper_hull_slope(lx, ly) or nominal, periods[0]), periods[1])
        half = 0.5 * max(high - low, 0.0) + tol
        spread = max(best - periods[0], periods[1] - best)
        self._line = (int(n_ref), t_ref + 0.5 * (low + high), best, half, spread)
        self._state = "locked"
        if self._fitted:
            self._check_rate(1.0 / best)

    def _update_hulls(self) -> None:
        if self._new_frames >= self.rebuild_every or not self._lo_hull or not self._hi_hull:
            self._new_frames = 0
            self._lo_hull = _hull(list(self._lo), upper=True)
            self._hi_hull = _hull(list(self._hi), upper=False)
            return
        # Only the points since the last refresh can add vertices; the tightened last lower
        # point replaces its older value.
        for hull, points, upper in (
            (self._lo_hull, self._lo, True),
            (self._hi_hull, self._hi, False),
        ):
            last = hull[-1][0]
            tail = []
            for p in reversed(points):
                if p[0] < last:
                    break
                tail.append(p)
            merged = [v for v in hull if v[0] < tail[-1][0]] + tail[::-1] if tail else hull
            hull[:] = _hull(merged, upper=upper)

    def _drop_contradictions(self, n_ref: int, t_ref: float) -> bool:
        """Drop the upper points that lie below the best line through the lower points, if they
        are few; True when some were dropped."""
        lx, ly = _relative(self._lo_hull, n_ref, t_ref)
        period = _upper_hull_slope(lx, ly)
        if period is None:
            return False
        line = float(np.max(ly - period * lx))
        hi = np.asarray(self._hi, float)
        below = hi[:, 1] - t_ref - period * (hi[:, 0] - n_ref) < line - self.tolerance_s
        n = int(np.count_nonzero(below))
        if n == 0 or n > max(1.0, self.max_contradictions * len(hi)):
            return False
        self.dropped += n
        self._hi = deque(p for p, bad in zip(self._hi, below.tolist(), strict=True) if not bad)
        self._new_frames = self.rebuild_every
        self._update_hulls()
        return True

    def _inconsistent(self, why: str) -> None:
        self._state = "inconsistent"
        if self._warned_inconsistent:
            return
        self._warned_inconsistent = True
        log.warning(
            "the frame numbers from %s contradict its poll times (%s; configured frame_rate_hz "
            "= %g Hz): samples are stamped at the midpoint of their own poll interval meanwhile "
            "(uncertainty several ms). Check frame_rate_hz; if it is right, the tracker acts on "
            "commands later than assumed (raise command_delay_spread_s) or sooner (lower "
            "command_delay_s, e.g. for a network tracker)",
            self.name,
            why,
            self.frame_rate_hz,
        )

    def _check_rate(self, rate: float) -> None:
        if abs(rate / self.frame_rate_hz - 1.0) > self.rate_tolerance and not self._warned_rate:
            self._warned_rate = True
            log.warning(
                "%s delivers frames at %.6g Hz by the host clock, not the configured "
                "frame_rate_hz = %g Hz: the fitted rate is used, but check the setting against "
                "the tracker model's frame rate",
                self.name,
                rate,
                self.frame_rate_hz,
            )


def _relative(
    points: list[tuple[int, float]], n_ref: int, t_ref: float
) -> tuple[np.ndarray, np.ndarray]:
    arr = np.asarray(points, float)
    return arr[:, 0] - n_ref, arr[:, 1] - t_ref


def _hull(points: list[tuple[int, float]], upper: bool) -> list[tuple[int, float]]:
    """The upper (or lower) convex hull of ``points`` sorted by frame, one point per frame."""
    sign = 1.0 if upper else -1.0
    hull: list[tuple[int, float]] = []
    x0, y0 = points[0]
    for p in points:
        px, py = p[0] - x0, sign * (p[1] - y0)
        while len(hull) >= 2:
            (ax, ay), (bx, by) = hull[-2], hull[-1]
            ax, ay, bx, by = ax - x0, sign * (ay - y0), bx - x0, sign * (by - y0)
            # Keep b only if a -> b -> p turns clockwise (b above the chord a-p).
            if (bx - ax) * (py - ay) - (by - ay) * (px - ax) >= 0:
                hull.pop()
            else:
                break
        hull.append(p)
    return hull


def _period_range(
    lx: np.ndarray, ly: np.ndarray, ux: np.ndarray, uy: np.ndarray, tol: float
) -> tuple[float, float] | None:
    """The periods T for which some line t = c + T x passes above every lower point (lx, ly)
    and below every upper point (ux, uy), within ``tol``; None when there are none. Every pair
    of a lower and an upper point bounds T on one side."""
    dx = ux[None, :] - lx[:, None]
    dy = uy[None, :] - ly[:, None] + tol
    if np.any((dx == 0) & (dy < 0)):
        return None
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = dy / dx
    lo = float(np.max(ratio[dx < 0], initial=-math.inf))
    hi = float(np.min(ratio[dx > 0], initial=math.inf))
    return (max(lo, 0.0), hi) if max(lo, 0.0) <= hi else None


def _lowest_max(x: np.ndarray, y: np.ndarray, periods: tuple[float, float]) -> float:
    """min over T in ``periods`` of max_i (y_i - T x_i): the earliest time at x = 0 of a line
    above every point (x, y) with a period in the range. Convex in T: the minimum is at an end
    or at a hull edge's slope."""
    edges = np.diff(y) / np.diff(x) if len(x) > 1 else np.array([])
    ts = np.concatenate(
        [[periods[0], periods[1]], edges[(edges > periods[0]) & (edges < periods[1])]]
    )
    return float(np.min(np.max(y[None, :] - ts[:, None] * x[None, :], axis=1)))


def _highest_min(x: np.ndarray, y: np.ndarray, periods: tuple[float, float]) -> float:
    """max over T in ``periods`` of min_j (y_j - T x_j): the latest time at x = 0 of a line
    below every point (x, y) with a period in the range."""
    edges = np.diff(y) / np.diff(x) if len(x) > 1 else np.array([])
    ts = np.concatenate(
        [[periods[0], periods[1]], edges[(edges > periods[0]) & (edges < periods[1])]]
    )
    return float(np.max(np.min(y[None, :] - ts[:, None] * x[None, :], axis=1)))


def _upper_hull_slope(x: np.ndarray, y: np.ndarray) -> float | None:
    """The slope of the upper hull's edge (vertices (x, y), x increasing) over the mean of the
    points it was built from: the line on or above every point closest to them on average
    (Moon, Skelly and Towsley's linear-programming clock skew estimate, upside down). Given the
    hull only, the mean of its vertices' span stands in. None with fewer than two vertices."""
    if len(x) < 2:
        return None
    xm = 0.5 * (float(x[0]) + float(x[-1]))
    k = int(np.searchsorted(x, xm))
    k = min(max(k, 1), len(x) - 1)
    return float((y[k] - y[k - 1]) / (x[k] - x[k - 1]))
