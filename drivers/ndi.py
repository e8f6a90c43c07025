"""Driver for optical / electromagnetic pose trackers speaking the NDI Combined API (Polaris,
Aurora and compatible), over any pyserial port: a device path, ``socket://host:port``, a pty or
a mock URL such as ``ndimock://`` (ports are opened with :func:`serial.serial_for_url`).

:class:`NDITracker` resets the tracker, sets the baud rate, enables the tools and polls ``TX`` /
``BX`` frames; every reply is CRC-checked and parsed before it becomes a pose, and each frame is
stamped with the instant the tracker measured it, from its frame number. The wire protocol, the
reply layouts, what is refused and how frames are timed are explained in ``docs/ndi.md`` ("How
the driver talks to the tracker"). The code tables are in :mod:`hexcal.drivers.ndi_codes`, the
reply parsers, errors and frames in :mod:`hexcal.drivers.ndi_protocol`, the frame clock in
:mod:`hexcal.drivers.ndi_clock`; their public names are importable from here too.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from dataclasses import replace
from typing import Literal, cast

import serial

from hexcal.acquire.acquisition import TrackerSample
from hexcal.drivers.base import SerialDevice
from hexcal.drivers.limits import check_duration
from hexcal.drivers.ndi_clock import FrameClock
from hexcal.drivers.ndi_clock import FrameTime as FrameTime
from hexcal.drivers.ndi_codes import (
    BAUD_CODES,
    BITS_PER_BYTE,
    REPLY_ALL_TRANSFORMS,
    REPLY_TRANSFORMS,
    SYSTEM_LINK_BITS,
    SYSTEM_NOTICE_BITS,
)
from hexcal.drivers.ndi_codes import BX_DISABLED as BX_DISABLED
from hexcal.drivers.ndi_codes import BX_MISSING as BX_MISSING
from hexcal.drivers.ndi_codes import BX_START as BX_START
from hexcal.drivers.ndi_codes import BX_VALID as BX_VALID
from hexcal.drivers.ndi_codes import ERROR_HINT as ERROR_HINT
from hexcal.drivers.ndi_codes import ERROR_TEXT as ERROR_TEXT
from hexcal.drivers.ndi_codes import MAX_POSITION_MM as MAX_POSITION_MM
from hexcal.drivers.ndi_codes import PORT_ALGORITHM_LIMITATION as PORT_ALGORITHM_LIMITATION
from hexcal.drivers.ndi_codes import PORT_DATA_BUFFER_LIMITATION as PORT_DATA_BUFFER_LIMITATION
from hexcal.drivers.ndi_codes import PORT_ENABLED as PORT_ENABLED
from hexcal.drivers.ndi_codes import PORT_FAULT_BITS as PORT_FAULT_BITS
from hexcal.drivers.ndi_codes import PORT_FELL_BEHIND as PORT_FELL_BEHIND
from hexcal.drivers.ndi_codes import PORT_INITIALIZED as PORT_INITIALIZED
from hexcal.drivers.ndi_codes import PORT_IR_INTERFERENCE as PORT_IR_INTERFERENCE
from hexcal.drivers.ndi_codes import PORT_OCCUPIED as PORT_OCCUPIED
from hexcal.drivers.ndi_codes import PORT_OUT_OF_VOLUME as PORT_OUT_OF_VOLUME
from hexcal.drivers.ndi_codes import PORT_PARTIALLY_IN_VOLUME as PORT_PARTIALLY_IN_VOLUME
from hexcal.drivers.ndi_codes import PORT_PROCESSING_EXCEPTION as PORT_PROCESSING_EXCEPTION
from hexcal.drivers.ndi_codes import PORT_STATUS_BITS as PORT_STATUS_BITS
from hexcal.drivers.ndi_codes import PORT_SWITCH_1 as PORT_SWITCH_1
from hexcal.drivers.ndi_codes import PORT_SWITCH_2 as PORT_SWITCH_2
from hexcal.drivers.ndi_codes import PORT_SWITCH_3 as PORT_SWITCH_3
from hexcal.drivers.ndi_codes import QUATERNION_NORM_TOLERANCE as QUATERNION_NORM_TOLERANCE
from hexcal.drivers.ndi_codes import SYSTEM_CONFIGURATION_CHANGED as SYSTEM_CONFIGURATION_CHANGED
from hexcal.drivers.ndi_codes import SYSTEM_DIAGNOSTIC_PENDING as SYSTEM_DIAGNOSTIC_PENDING
from hexcal.drivers.ndi_codes import SYSTEM_FAULT_BITS as SYSTEM_FAULT_BITS
from hexcal.drivers.ndi_codes import SYSTEM_PORT_OCCUPIED as SYSTEM_PORT_OCCUPIED
from hexcal.drivers.ndi_codes import SYSTEM_PORT_UNOCCUPIED as SYSTEM_PORT_UNOCCUPIED
from hexcal.drivers.ndi_codes import SYSTEM_PROCESSING_EXCEPTION as SYSTEM_PROCESSING_EXCEPTION
from hexcal.drivers.ndi_codes import SYSTEM_STATUS_BITS as SYSTEM_STATUS_BITS
from hexcal.drivers.ndi_codes import SYSTEM_STATUS_HINT as SYSTEM_STATUS_HINT
from hexcal.drivers.ndi_codes import SYSTEM_SYNC_ERROR as SYSTEM_SYNC_ERROR
from hexcal.drivers.ndi_codes import SYSTEM_TEMPERATURE as SYSTEM_TEMPERATURE
from hexcal.drivers.ndi_link import _PORT_ERRORS, Exchange, SerialLink
from hexcal.drivers.ndi_protocol import ToolReport as ToolReport
from hexcal.drivers.ndi_protocol import TrackerCRCError as TrackerCRCError
from hexcal.drivers.ndi_protocol import (
    TrackerDisconnected,
    TrackerError,
    TrackerFrame,
    TrackerReplyError,
    build_command,
    checked_payload,
    parse_bx_reply,
    parse_phsr_reply,
    parse_tx_reply,
)
from hexcal.drivers.ndi_protocol import TrackerFormatError as TrackerFormatError
from hexcal.drivers.ndi_protocol import TrackerTimeout as TrackerTimeout
from hexcal.drivers.ndi_protocol import UnoccupiedPort as UnoccupiedPort
from hexcal.drivers.ndi_protocol import error_text as error_text
from hexcal.drivers.ndi_protocol import pose_defect as pose_defect

log = logging.getLogger(__name__)

# pyserial reads block in slices this long (s), so a reply's deadline is kept to within it
# without reconfiguring the port's timeout (which reprograms the UART on every change).
_READ_SLICE_S = 0.02


# ------------------------------------------------------------------------------------------------
# The driver
# ------------------------------------------------------------------------------------------------
#: A timing warning that clears and comes back is given again after this long at the soonest, s.
WARNING_REPEAT_S = 60.0


def jitter_suspects(url: str) -> str:
    """What to check when replies on ``url`` come at irregular delays: the USB hub or adapter
    of a serial device, the network of a socket, the host alone for a simulated tracker (a
    pyserial URL handler such as ``ndimock://`` runs on this computer)."""
    scheme = url.split("://", 1)[0].lower() if "://" in url else ""
    if not scheme:
        return "the host load or the USB hub/adapter"
    if scheme in ("socket", "rfc2217"):
        return "the host load or the network"
    return "the host load (the tracker behind this URL handler runs on this computer)"


class NDITracker(SerialLink, SerialDevice):
    """An NDI Combined API tracker on a pyserial port (``url``: a device path, ``socket://``,
    a pty, ``ndimock://``...).

    ``baudrate`` is the working rate set by COMM after the reset at 9600; ``timeout`` (s) bounds
    each ordinary reply. Every duration (s) must be finite and at most
    :data:`~hexcal.drivers.limits.MAX_TIMEOUT_S` (timeouts also > 0): ValueError naming the
    parameter otherwise, never a wait without end. ``reset``: ``"break"`` (a serial BREAK: real
    RS-232 and USB ports), ``"command"`` (``RESET:0``: ports that cannot carry a BREAK, such as
    ptys and TCP bridges), ``"auto"`` (BREAK, then the command if no answer in
    ``reset_timeout_s``). ``settle_s`` is the pause after COMM and INIT that ndicapi also makes;
    ``tool_mode`` the PENA tracking priority.
    ``pose_handle`` selects the tool :meth:`sample` reports (default: the first enabled one).
    ``out_of_volume_transforms`` polls with reply option 0x0800 (``TX:0801`` / ``BX:0801``): the
    tracker then reports the pose of a tool outside its characterised measurement volume, which
    the sample keeps (refused, unless ``accept_out_of_volume``) so that the operator reads where
    the tool is and to move it back into the volume. A tracker that refuses the option (an
    ``ERRORxx`` to it, while the same poll without it succeeds) is polled without it from then
    on, with a warning.

    Timing (see :class:`FrameClock` and docs/ndi.md): ``frame_rate_hz`` is the
    tracker's nominal frame rate (Polaris 60 Hz), fitted from the polls when
    ``fit_frame_rate``; ``command_delay_s`` the least time (s) from handing a command to the
    port to the tracker acting on it — None: the command's transfer time at ``baudrate``
    (10 bits per byte), which no serial link can beat; ``command_delay_spread_s`` how much
    later (s) than that, after the write returned, the tracker may act (USB scheduling, the
    tracker's own parsing; too small a value shows as contradicting frame times, which
    :meth:`clock_stats` counts and a warning names). The tracker's answer *after* acting
    (processing, reply transfer, host latency) does not matter. ``frame_latency_s`` is how long
    (s) before a frame is available to a command the tracker exposed it: a constant of the
    tracker no host-side timing can see (0 for the mock; measure it once, e.g. against a
    motion of known timing), subtracted from every stamp.

    Typical use::

        with NDITracker("/dev/ttyUSB0") as trk:   # open(): reset, COMM, INIT
            trk.setup_tools()
            trk.start()
            frame = trk.poll()                   # TX:0001 -> TrackerFrame

    Not thread-safe beyond one lock around each exchange: use it from one thread at a time.
    """

    def __init__(
        self,
        url: str,
        baudrate: int = 115200,
        timeout: float = 1.0,
        *,
        reset: Literal["auto", "break", "command"] = "auto",
        reset_timeout_s: float = 3.0,
        break_duration_s: float = 0.25,
        settle_s: float = 0.1,
        tool_mode: Literal["D", "S", "B"] = "D",
        pose_handle: int | None = None,
        accept_out_of_volume: bool = False,
        out_of_volume_transforms: bool = True,
        max_jitter_s: float = 0.02,
        resync_s: float = 0.05,
        frame_rate_hz: float = 60.0,
        fit_frame_rate: bool = True,
        command_delay_s: float | None = None,
        command_delay_spread_s: float = 0.5e-3,
        frame_latency_s: float = 0.0,
    ):
        if baudrate not in BAUD_CODES:
            rates = ", ".join(str(b) for b in BAUD_CODES)
            raise ValueError(
                f"the NDI API has no baud rate {baudrate} (port {url}); use one of {rates}"
            )
        if reset not in ("auto", "break", "command"):
            raise ValueError(f"reset must be 'auto', 'break' or 'command', not {reset!r}")
        self.url = url
        self.baudrate = baudrate
        # Bounded waits only: inf reached pyserial's write_timeout and crashed it.
        self.timeout = check_duration("timeout", timeout)
        self.reset = reset
        self.reset_timeout_s = check_duration("reset_timeout_s", reset_timeout_s)
        self.break_duration_s = check_duration("break_duration_s", break_duration_s)
        self.settle_s = check_duration("settle_s", settle_s, allow_zero=True)
        self.tool_mode = tool_mode
        self.pose_handle = pose_handle
        self.accept_out_of_volume = accept_out_of_volume
        self.out_of_volume_transforms = out_of_volume_transforms
        # Per command (TX, BX): None until the tracker answered the 0x0800 option, True once it
        # did, False once it refused it (then polls go without it until the next open()).
        self._all_transforms: dict[str, bool | None] = {"TX": None, "BX": None}
        self._last_notice = 0  # the system status notice bits of the previous frame
        self._warned_at = -math.inf  # when the timing warning was last given (monotonic s)
        self.max_jitter_s = check_duration("max_jitter_s", max_jitter_s)
        self.resync_s = check_duration("resync_s", resync_s, allow_zero=True)
        self.port: serial.Serial | None = None
        self.handles: tuple[int, ...] = ()
        self.tracking = False
        self.version = ""
        #: A sentence when the reply latency varies more than ``max_jitter_s``, else None.
        self.timing_warning: str | None = None
        self._lock = threading.RLock()
        self._dead = False  # the port failed: only reconnect() helps
        self._resume_tracking = False  # it was tracking when the port failed
        self._resync = False  # a reply timed out: it may still arrive late
        self._latencies: deque[float] = deque(maxlen=50)
        self._last_sample_frame: int | None = None
        self.command_delay_s = (
            None
            if command_delay_s is None
            else check_duration("command_delay_s", command_delay_s, allow_zero=True)
        )
        self.command_delay_spread_s = check_duration(
            "command_delay_spread_s", command_delay_spread_s, allow_zero=True
        )
        self.frame_latency_s = check_duration("frame_latency_s", frame_latency_s, allow_zero=True)
        #: Maps frame numbers to host times (see :meth:`clock_stats`).
        self.frame_clock = FrameClock(frame_rate_hz, fit_rate=fit_frame_rate, name=url)
        self._clock_suspect = False  # an exchange failed: the next reply may be a stale one

    def __repr__(self) -> str:
        state = "tracking" if self.tracking else ("open" if self.port is not None else "closed")
        return f"NDITracker({self.url!r}, {self.baudrate} baud, {state})"

    # -- connection -----------------------------------------------------------------------------
    def open(self) -> NDITracker:
        """Open the port, reset the tracker, set the baud rate (COMM) and initialise it (INIT)."""
        with self._lock:
            self._close_port()
            try:
                # serial_for_url returns the URL handler's class: a serial.Serial subclass
                # (or Serial itself) for every handler hexcal uses.
                self.port = cast(
                    serial.Serial,
                    serial.serial_for_url(
                        self.url, baudrate=9600, timeout=_READ_SLICE_S, write_timeout=self.timeout
                    ),
                )
            except _PORT_ERRORS as exc:
                raise TrackerDisconnected(
                    f"cannot open the tracker port {self.url}: {exc}. Check the port name, that the "
                    "cable or USB adapter is plugged in, and that no other program holds the port",
                    self.url,
                ) from exc
            self._dead = False
            self._resync = False
            self.tracking = False
            self.handles = ()
            # A reset tracker may count frames afresh: nothing learned so far holds.
            self.frame_clock.reset()
            self._clock_suspect = False
            self._last_sample_frame = None
            self._all_transforms = {"TX": None, "BX": None}
            self._last_notice = 0
            try:
                self._reset_tracker()
                if self.baudrate != 9600:
                    self.command(f"COMM:{BAUD_CODES[self.baudrate]}0000")
                    time.sleep(self.settle_s)  # the tracker switches after its OKAY has gone out
                    self._set_baud(self.baudrate)
                self.command("INIT:", timeout=max(self.timeout, 5.0))
                time.sleep(self.settle_s)
                try:
                    self.version = self.command("VER:4").decode("ascii", "replace").strip()
                except TrackerReplyError:  # older firmware: the version is a courtesy
                    self.version = ""
            except BaseException:
                self._close_port()  # half-open is no state to leave a port in
                raise
            log.info("tracker on %s ready at %d baud: %s", self.url, self.baudrate, self.version)
            return self

    def setup_tools(self) -> tuple[int, ...]:
        """Free stale port handles, initialise and enable every tool found (PHSR, PHF, PINIT,
        PENA); returns the enabled handles (also in :attr:`handles`)."""
        with self._lock:
            for handle in self._phsr(1):
                self.command(f"PHF:{handle:02X}")
            # Initialising a handle can reveal more (e.g. a splitter's second channel): repeat.
            for _ in range(3):
                pending = self._phsr(2)
                if not pending:
                    break
                for handle in pending:
                    self.command(f"PINIT:{handle:02X}", timeout=max(self.timeout, 5.0))
            for handle in self._phsr(3):
                self.command(f"PENA:{handle:02X}{self.tool_mode}")
            self.handles = tuple(self._phsr(4))
            if not self.handles:
                raise TrackerError(
                    f"the tracker on {self.url} reports no enabled tool: plug the tool in (wired and "
                    "Aurora tools) or load its tool definition (passive tools, not supported by this "
                    "driver), then call setup_tools() again",
                    self.url,
                )
            return self.handles

    def start(self) -> None:
        """Enter tracking mode (TSTART)."""
        with self._lock:
            self.command("TSTART:", timeout=max(self.timeout, 5.0))
            self.tracking = True
            self._latencies.clear()

    def stop(self) -> None:
        """Leave tracking mode (TSTOP)."""
        with self._lock:
            self.command("TSTOP:", timeout=max(self.timeout, 5.0))
            self.tracking = False

    def connect(self) -> NDITracker:
        """open() (unless the port is open already, as inside ``with``), setup_tools() and
        start() in one call."""
        if self.port is None or self._dead:
            self.open()
        self.setup_tools()
        self.start()
        return self

    def reconnect(self, wait_s: float = 0.0) -> NDITracker:
        """After :class:`TrackerDisconnected`: reopen the same port (retrying for up to
        ``wait_s`` seconds while it is absent), reset, set up the tools and resume tracking if it
        was tracking."""
        was_tracking = self.tracking or self._resume_tracking
        deadline = time.monotonic() + wait_s
        while True:
            try:
                self.open()
                break
            except TrackerDisconnected:
                if time.monotonic() >= deadline:
                    raise
                time.sleep(0.1)
        self.setup_tools()
        if was_tracking:
            self.start()
        self._resume_tracking = False
        return self

    @property
    def lost(self) -> bool:
        """The connection failed (:class:`TrackerDisconnected`): only :meth:`reconnect` helps."""
        return self._dead

    def mark_lost(self, exc: BaseException) -> None:
        """Take the connection as lost after ``exc`` (a reconnect that failed half way)."""
        with self._lock:
            self._lost(exc)

    def close(self) -> None:
        """Stop tracking, put the tracker back to 9600 baud (so the next session can reset it by
        command too) and close the port. Never raises for a port that is already gone."""
        with self._lock:
            if self.port is not None and not self._dead:
                try:
                    if self.tracking:
                        self.stop()
                    if self.baudrate != 9600:
                        self.command("COMM:00000")
                except TrackerError as exc:
                    log.warning("closing the tracker on %s: %s", self.url, exc)
            self.tracking = False
            self._close_port()

    # -- tracking -------------------------------------------------------------------------------
    def poll(self) -> TrackerFrame:
        """One ``TX`` frame (reply option 0x0001, and 0x0800 with
        :attr:`out_of_volume_transforms`): every handle's pose or MISSING status, the frame
        number, the system status, the host receive time and the frame's measurement time."""
        return self._poll("TX", binary=False)

    def poll_binary(self) -> TrackerFrame:
        """One ``BX`` frame (float32 values: finer than TX's text resolution)."""
        return self._poll("BX", binary=True)

    def reply_option(self, name: str = "TX") -> int:
        """The reply option the next ``name`` (TX or BX) poll sends."""
        if self.out_of_volume_transforms and self._all_transforms.get(name) is not False:
            return REPLY_TRANSFORMS | REPLY_ALL_TRANSFORMS
        return REPLY_TRANSFORMS

    def _poll(self, name: str, binary: bool) -> TrackerFrame:
        with self._lock:
            option = self.reply_option(name)
            try:
                return self._poll_once(f"{name}:{option:04X}", binary)
            except TrackerReplyError as exc:
                if not option & REPLY_ALL_TRANSFORMS or self._all_transforms[name]:
                    raise
                # The tracker may not know the option: the same poll without it decides.
                plain = f"{name}:{REPLY_TRANSFORMS:04X}"
                frame = self._poll_once(plain, binary)
                self._all_transforms[name] = False
                log.warning(
                    "the tracker on %s refused reply option 0800 (ERROR%02X to %s:%04X) but "
                    "answers %s: polling without it, so a tool outside the measurement volume "
                    "is reported MISSING rather than with its pose",
                    self.url,
                    exc.code,
                    name,
                    option,
                    plain,
                )
                return frame

    def _poll_once(self, command: str, binary: bool) -> TrackerFrame:
        parse = parse_bx_reply if binary else parse_tx_reply
        try:
            ex = self._exchange(command, self.timeout, binary=binary)
            frame = parse(
                ex.raw, ex.t_recv, port=self.url, command=command, latency_s=ex.t_recv - ex.t_sent
            )
        except TrackerError:
            self._clock_suspect = True
            raise
        if int(command[3:], 16) & REPLY_ALL_TRANSFORMS:
            self._all_transforms[command[:2]] = True
        frame = self._stamp(frame, command, ex)
        self._note_frame(frame)
        return frame

    def _stamp(self, frame: TrackerFrame, command: str, ex: Exchange) -> TrackerFrame:
        """``frame`` with its measurement time from the frame clock, which it also feeds."""
        number = frame.frame_number
        if number is None:
            return frame
        if self._clock_suspect:
            # After a failed exchange this reply may answer an earlier command (a late one that
            # escaped the resync): its frame number maps to a time all the same, but its bounds
            # would be wrong, so it teaches the clock nothing.
            self._clock_suspect = False
        else:
            delay = self._command_delay(command)
            self.frame_clock.observe(
                number,
                ex.t_write + delay,
                min(ex.t_sent + delay + self.command_delay_spread_s, ex.t_recv),
                ex.t_recv,
            )
        when = self.frame_clock.time_of(number)
        return replace(
            frame,
            measured_at=when.t - self.frame_latency_s,
            timing_uncertainty_s=when.uncertainty_s,
        )

    def _command_delay(self, command: str) -> float:
        """The least time (s) from writing ``command`` to the tracker acting on it."""
        if self.command_delay_s is not None:
            return self.command_delay_s
        baud = self.port.baudrate if self.port is not None else self.baudrate
        return len(build_command(command)) * BITS_PER_BYTE / baud

    def sample(self, binary: bool = False) -> TrackerSample:
        """The next new frame (frame number changed) as a :class:`TrackerSample` of
        :attr:`pose_handle`: the acquisition's :class:`~hexcal.acquire.acquisition.PoseSource`.

        A tool missing or out of volume, a bad system status, or a frame counter that stopped
        for ``timeout`` s gives a sample with ``fault`` set; a link failure raises
        (:class:`TrackerError`)."""
        deadline = time.monotonic() + self.timeout
        while True:
            frame = self.poll_binary() if binary else self.poll()
            number = frame.frame_number
            if number is None or number != self._last_sample_frame:
                self._last_sample_frame = number
                return frame.to_sample(self.pose_handle, self.accept_out_of_volume)
            if time.monotonic() > deadline:
                stale = (
                    f"the tracker on {self.url} has repeated frame {number} for {self.timeout:g} s: "
                    "it stopped measuring. Check the camera / field generator, or reopen it"
                )
                return TrackerSample(frame.received_at, None, None, fault=stale)
            time.sleep(0.002)  # polled faster than the tracker's frame rate: same frame again

    def clock_stats(self) -> dict[str, float | int | str | bool]:
        """The frame clock now (:meth:`FrameClock.stats`): ``state`` ("warming up", "locked",
        "inconsistent"), ``uncertainty_s`` (half-width of the interval a frame's measurement
        time is known to lie in, s), ``frame_rate_hz`` (fitted when ``rate_fitted``),
        ``rate_offset_ppm``, ``frames``, ``span_s``, ``contradictions``, ``resets``; plus the
        ``command_delay_s`` (at the current baud rate) and ``command_delay_spread_s`` assumed."""
        with self._lock:
            stats = self.frame_clock.stats()
            stats["command_delay_s"] = self._command_delay("TX:0001")
            stats["command_delay_spread_s"] = self.command_delay_spread_s
            return stats

    def latency_stats(self) -> dict[str, float]:
        """Reply latency over the last polls: n, mean_s, min_s, max_s, spread_s."""
        lat = list(self._latencies)
        if not lat:
            return {
                "n": 0,
                "mean_s": math.nan,
                "min_s": math.nan,
                "max_s": math.nan,
                "spread_s": math.nan,
            }
        return {
            "n": len(lat),
            "mean_s": sum(lat) / len(lat),
            "min_s": min(lat),
            "max_s": max(lat),
            "spread_s": max(lat) - min(lat),
        }

    # -- commands -------------------------------------------------------------------------------
    def command(self, command: str, timeout: float | None = None) -> bytes:
        """Send an ASCII command; return its checked payload (CRC removed). Raises
        :class:`TrackerReplyError` for ``ERRORxx`` and the link errors."""
        timeout = self.timeout if timeout is None else check_duration("timeout", timeout)
        with self._lock:
            raw = self._exchange(command, timeout).raw
            payload = checked_payload(raw, self.url, command)
            if payload[:7] == b"WARNING":
                log.warning(
                    "tracker on %s answered %r with %s",
                    self.url,
                    command,
                    payload.decode("ascii", "replace"),
                )
            return payload

    def _phsr(self, option: int) -> list[int]:
        command = f"PHSR:{option:02X}"
        return [h for h, _ in parse_phsr_reply(self.command(command), self.url, command)]

    def _note_frame(self, frame: TrackerFrame) -> None:
        if frame.system_status & SYSTEM_LINK_BITS:
            for problem in frame.system_problems(SYSTEM_LINK_BITS):
                log.warning("%s (earlier commands may have been lost: check the cable)", problem)
        notice = frame.system_status & SYSTEM_NOTICE_BITS
        if notice & ~self._last_notice:  # said once when it appears, not at every frame
            for problem in frame.system_problems(notice & ~self._last_notice):
                log.warning(
                    "%s (read the tracker's alerts with NDI's tools if poses fail)", problem
                )
        self._last_notice = notice
        self._latencies.append(frame.latency_s)
        if len(self._latencies) < 10:
            return
        st = self.latency_stats()
        if st["spread_s"] > self.max_jitter_s:
            now = time.monotonic()
            if self.timing_warning is None and now - self._warned_at >= WARNING_REPEAT_S:
                self._warned_at = now
                self.timing_warning = (
                    f"the tracker on {self.url} answers with an irregular delay: "
                    f"{st['min_s'] * 1e3:.1f} to {st['max_s'] * 1e3:.1f} ms over the last {st['n']} "
                    f"polls (jitter {st['spread_s'] * 1e3:.1f} ms > {self.max_jitter_s * 1e3:.0f} ms), "
                    "so host receive times are uncertain by that much. Samples are stamped from the "
                    "tracker's frame numbers (clock_stats()), which this does not upset, but check "
                    f"{jitter_suspects(self.url)}"
                )
                # A note, not a warning: samples are stamped from the frame numbers, so the
                # data are not upset (a busy host, a UI drawing in the same process, does this).
                log.info(self.timing_warning)
        elif st["spread_s"] < 0.5 * self.max_jitter_s:
            self.timing_warning = None
