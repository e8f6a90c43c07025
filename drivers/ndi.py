"""Driver for optical / electromagnetic pose trackers speaking the NDI Combined API (Polaris,
Aurora and compatible), over any pyserial port: a device path, ``socket://host:port``, a pty or
a mock URL such as ``ndimock://`` (ports are opened with :func:`serial.serial_for_url`).

What goes over the wire (as documented by the open drivers: PlusToolkit ndicapi,
scikit-surgerynditracker, sawNDITracker)
------------------------------------------------------------------------------------------------
Commands are ASCII. This driver sends the ``NAME:params`` form followed by the CRC of everything
before it (4 uppercase hex digits) and a CR, e.g. ``TX:0001`` + CRC + CR, so that the tracker
checks our commands too (it answers ``ERROR04`` to a corrupted one). The tracker also accepts the
``NAME params`` form without a CRC (``TX 0001`` + CR).

Every ASCII reply is ``<payload><CRC16><CR>``: the CRC-16/ARC (:mod:`hexcal.drivers.crc`) of the
payload as 4 uppercase hex digits. A failed command answers ``ERRORxx`` (xx hex, see
:data:`ERROR_TEXT`); some answer ``WARNINGxx`` and still succeed. Success is usually ``OKAY``.

Connection sequence (:meth:`NDITracker.open`):

1. Reset. A serial BREAK at 9600 baud makes the tracker reset to 9600 baud 8N1 and answer
   ``RESETBE6F`` (``RESET`` + its CRC ``BE6F``). A pseudo-terminal, a ``socket://`` bridge and
   some USB adapters cannot carry a BREAK; for those the ``RESET:0`` command does the same (tried
   at 9600 baud, then at the working baud rate in case a previous session left the tracker
   there, then at 9600 again). ``reset="auto"`` tries the BREAK first, then the command.
2. ``COMM:<b>0000`` sets the baud rate (``b`` from :data:`BAUD_CODES`: ``0`` to ``7`` for 9600
   to 1228739 baud, ``A`` for 230400; 8N1, no handshake); the tracker answers ``OKAY`` at the
   old rate, then both sides switch.
3. ``INIT:`` initialises the system.

Tools (:meth:`NDITracker.setup_tools`): ``PHSR:0x`` lists port handles: 2 hex digits (count),
then per handle 2 hex digits (handle) + 3 hex digits (handle status). ``PHSR:01`` lists handles
to free (``PHF:hh``), ``PHSR:02`` those to initialise (``PINIT:hh``), ``PHSR:03`` those to enable
(``PENA:hh<mode>``, mode ``D`` dynamic, ``S`` static, ``B`` button box), ``PHSR:04`` the enabled
ones. Wired (active / Aurora) tools are found this way; passive tools need their ROM file loaded
first (``PVWR``), which this driver does not do.

Tracking: ``TSTART:`` / ``TSTOP:``. ``TX:0001`` (transforms and status; ``TX:0801`` adds reply
option 0x0800, the transforms the tracker does not normally report, such as a tool outside the
characterised volume: same layout, see :data:`REPLY_ALL_TRANSFORMS`) replies::

    nn                                   number of handle records, 2 hex digits
    then per handle, each record ending in LF (0x0A):
      hh                                 port handle, 2 hex digits
      then one of
        Q0 Qx Qy Qz   4 x 6 chars        unit quaternion, scalar first: sign + 5 digits, x 1e-4
        Tx Ty Tz      3 x 7 chars        position, mm: sign + 6 digits, x 0.01
        Err           6 chars            RMS fit error, mm: sign + 5 digits, x 1e-4
        ssssssss      8 hex              port status (:data:`PORT_STATUS_BITS`)
        ffffffff      8 hex              frame number
      or MISSING ssssssss ffffffff       tool not seen: port status and frame number only
      or DISABLED [ssssssss ffffffff]    handle not enabled (no pose)
      or UNOCCUPIED [ssssssss ffffffff]  nothing in that port (no pose; the other handles'
                                         records stand: TrackerFrame.unoccupied)
    ssss                                 system status, 4 hex (:data:`SYSTEM_STATUS_BITS`)
    CRC16 CR

The bracketed status and frame number may be there or not: ndicapi reads the bare words,
sawNDITracker reads both fields after them; either is accepted. Port status bits 8-15
(:data:`PORT_FAULT_BITS`: algorithm limitation, IR interference, processing exception, fell
behind while processing, data buffer limitation, and the reserved bits 10, 11, 13) each refuse
the tool's pose with the bit's name; the system status follows the current API guide's table.

A pose record is thus 2 + 51 + 16 = 69 characters and LF. Mind the text format's resolution:
1e-4 per quaternion component (rotation rounding up to about 0.01 deg, 0.006 deg typical) and
0.01 mm in position, coarser than a good optical tracker's orientation noise. ``BX:0001`` (or
``BX:0801``) returns the same content in binary with IEEE-754 float32 (little endian), which
does not round::

    C4 A5                                start sequence (0xA5C4 little endian)
    LL LL                                body length, bytes (uint16 LE)
    CC CC                                CRC16 of the 4 bytes above (uint16 LE)
    body:
      n                                  number of handles (uint8)
      per handle: handle (uint8), handle status (uint8: 01 valid, 02 missing, 04 disabled),
        if valid: Q0 Qx Qy Qz Tx Ty Tz Err as 8 float32 (position and RMS error in mm)
        if valid or missing: port status (uint32 LE), frame number (uint32 LE)
      system status (uint16 LE)
    CC CC                                CRC16 of the body (uint16 LE)

Nothing unchecked becomes a pose: a reply whose CRC does not match, that stops short, or whose
content does not follow the format above raises (:class:`TrackerCRCError`,
:class:`TrackerTimeout`, :class:`TrackerFormatError`). A tool the tracker does not see is not an
error of the link: the frame reports it (``state == "missing"``) and :meth:`NDITracker.sample`
turns it into a fault sample, as it does a tool outside the characterised measurement volume
(whose pose, reported thanks to reply option 0x0800, the sample keeps for the operator's
message: where the tool is, and to move it back into the volume).
So does a pose record that passed every check of the link but carries a number no pose can
have — NaN or infinity in the position, the quaternion or the RMS error (BX's float32 can say
so; TX's fixed-width digits cannot), or a position beyond :data:`MAX_POSITION_MM` — the frame
is well formed, its frame number and status still count, but that tool's reading is a fault
(``state == "invalid"``, :attr:`ToolReport.defect` says which number), never a pose.

Timing: every frame carries the host receive time (``received_at``: ``time.monotonic()`` when
its last byte arrived) and the command-to-reply latency (``latency_s``), but neither says when
the pose was *measured*: the reply comes a latency later (serial transfer, the tracker's
processing, USB and host scheduling, all of it jittery), and the frame was measured up to one
frame period before the command even arrived. The tracker's frame number is the reliable clock:
frames come at a fixed rate, so frame n was measured at t(n) = t_ref + (n - n_ref) / f on the
host clock. Every poll bounds that line: a frame number first seen in the reply to a command
written at ``t_write(k)`` was measured after the previous poll reached the tracker (that poll
returned an older frame) and before this one did. A command cannot reach the tracker sooner
than its serial transfer time after it was written (``command_delay_s``), and the tracker acts
on it soon after (within ``command_delay_spread_s`` of the write returning); what happens after
it acted — the reply's latency and jitter — does not enter these bounds at all. The
:class:`FrameClock` combines the bounds of the frames of a sliding window (offset: the tightest
consistent interval; rate: ``frame_rate_hz`` within ``drift_ppm``, or fitted from the bounds so
that a tracker clock drifting against the host's is followed) and stamps each frame
``measured_at`` = t(n) - ``frame_latency_s``, which :meth:`TrackerFrame.to_sample` gives as
``TrackerSample.t``; :meth:`NDITracker.clock_stats` reports its state, its current uncertainty
(the interval's half-width) and the rate in use. On the mock tracker with a 5 to 8 ms reply
latency the stamps are within about 0.3 ms of the true instants (``benchmarks/alignment.py``).
Before enough frames (about half a second), or while the bounds contradict the rate, a frame is
stamped at the midpoint of its own poll interval, from the previous poll's write to this reply,
with that interval's larger half-width (a warning says so once). The clock restarts at each
:meth:`~NDITracker.open` and when the frame counter goes back or leaps. What no host-side timing
can see is how long before a frame becomes available the tracker exposed it: a constant of the
tracker, ``frame_latency_s`` (0 by default, as on the mock), to be measured once. When the reply
latency itself varies by more than ``max_jitter_s`` the driver says so (a logged warning and
:attr:`NDITracker.timing_warning`): the frame clock is not affected, but receive times are.

The driver is not a protocol analyser: after a failed exchange it flushes the input, and after a
timeout it also discards anything arriving in the next ``resync_s``, so that a late reply is not
taken for the answer to the next command.
"""

from __future__ import annotations

import logging
import math
import re
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from types import TracebackType
from typing import Literal, NamedTuple

import numpy as np
import serial

from hexcal.acquisition import TrackerSample
from hexcal.drivers.crc import crc16, crc16_hex
from hexcal.drivers.limits import check_duration

try:  # a hung-up tty makes tcflush raise termios.error, which is not an OSError
    import termios

    _IO_ERRORS: tuple[type[BaseException], ...] = (OSError, termios.error)
except ImportError:  # pragma: no cover - Windows
    _IO_ERRORS = (OSError,)

log = logging.getLogger(__name__)

#: Baud rate -> the code COMM takes (one character). ndicapi.h (NDI_9600 ... NDI_1228739 are 0
#: to 7; NDI_230400 is 10, which ndicapi.cxx's ndiCOMMHelper sends as the character "A").
BAUD_CODES: dict[int, str] = {
    9600: "0",
    14400: "1",
    19200: "2",
    38400: "3",
    57600: "4",
    115200: "5",
    921600: "6",
    1228739: "7",
    230400: "A",
}

#: Meaning of the tracker's ``ERRORxx`` codes, every code the Combined API defines up to 0x42
#: and the 0xF1 to 0xF6 group (ndicapi.h's NDI_* error defines and ndicapi.cxx's
#: ndiErrorString; "reserved" where the API guide reserves the code).
ERROR_TEXT: dict[int, str] = {
    0x01: "invalid command",
    0x02: "command too long",
    0x03: "command too short",
    0x04: "invalid CRC calculated for the command",
    0x05: "time-out on command execution",
    0x06: "unable to set up the new communication parameters",
    0x07: "incorrect number of command parameters",
    0x08: "invalid port handle selected",
    0x09: "invalid mode selected",
    0x0A: "invalid LED selected",
    0x0B: "invalid LED state selected",
    0x0C: "command is invalid while in the current operating mode",
    0x0D: "no tool is assigned to the selected port handle",
    0x0E: "selected port handle not initialised",
    0x0F: "selected port handle not enabled",
    0x10: "system not initialised",
    0x11: "unable to stop tracking",
    0x12: "unable to start tracking",
    0x13: "unable to initialise the port handle",
    0x14: "invalid camera / field generator characterisation parameters",
    0x15: "unable to initialise the system",
    0x16: "unable to start diagnostic mode",
    0x17: "unable to stop diagnostic mode",
    0x18: "unable to determine environmental infrared",
    0x19: "unable to read the firmware version",
    0x1A: "internal system error",
    0x1B: "unable to initialise for environmental infrared diagnostics",
    0x1C: "unable to set the marker firing signature",
    0x1D: "unable to search for SROM IDs",
    0x1E: "unable to read SROM data",
    0x1F: "unable to write SROM data",
    0x20: "unable to select SROM",
    0x21: "unable to perform the tool current test",
    0x22: "no camera parameters for this wavelength",
    0x23: "command parameter out of range",
    0x24: "no camera parameters for this volume",
    0x25: "unable to determine the supported features",
    0x26: "reserved error code 0x26",
    0x27: "reserved error code 0x27",
    0x28: "too many tools are enabled, the tools loaded need too many frames, "
    "or this tool type is not supported",
    0x29: "main processor firmware corrupt",
    0x2A: "no memory available for dynamic allocation (heap full)",
    0x2B: "the requested port handle has not been allocated",
    0x2C: "the requested port handle has become unoccupied",
    0x2D: "all port handles have been allocated",
    0x2E: "incompatible firmware versions",
    0x2F: "invalid port description",
    0x30: "the requested port is already assigned a port handle",
    0x31: "reserved error code 0x31",
    0x32: "invalid operation for the device associated with the port handle",
    0x33: "feature not available",
    0x34: "user parameter does not exist",
    0x35: "invalid value type (e.g. a string instead of an integer)",
    0x36: "user parameter value out of its valid range",
    0x37: "user parameter array index out of its valid range",
    0x38: "user parameter size incorrect",
    0x39: "permission denied: the file or user parameter is read-only, or a command that needs "
    "master mode came over a monitor-mode connection",
    0x3A: "reserved error code 0x3A",
    0x3B: "file not found",
    0x3C: "error writing to a file",
    0x3D: "error reading from a file",
    0x3E: "reserved error code 0x3E",
    0x3F: "reserved error code 0x3F",
    0x40: "tool definition file error (its CRC failed or its format is invalid)",
    0x41: "tool characteristics not supported (number of markers, faces, groups or markers per "
    "face outside what the system supports)",
    0x42: "device not present (the command is for a device that is not connected)",
    0xF1: "too much environmental infrared",
    0xF4: "unable to erase the flash memory",
    0xF5: "unable to write the flash memory",
    0xF6: "unable to read the flash memory",
}

#: What an operator can do about the common codes.
ERROR_HINT: dict[int, str] = {
    0x01: "the tracker does not know this command: check its model and firmware (VER)",
    0x04: "the command was corrupted on the way: check the cable and that both sides use the same baud rate",
    0x06: "the tracker refused the baud rate: choose another one (115200 is always supported)",
    0x0C: "the tracker is not in the right mode for this command (e.g. TX before TSTART): "
    "call start() after setup_tools(), or open() again to reset it",
    0x0D: "plug the tool in (or load its tool definition) and run setup_tools() again",
    0x0E: "run setup_tools() (PINIT) before enabling or tracking",
    0x0F: "run setup_tools() (PENA) before tracking",
    0x10: "open() the tracker (INIT) before this command",
    0x12: "check that a tool is enabled (setup_tools()) and that the tracker is not in diagnostic mode",
    0x13: "the tool definition is missing or the tool is faulty: check the tool and its cable",
    0x1A: "power-cycle the tracker; if it persists, contact NDI support",
    0x28: "enable fewer tools (or load fewer tool definitions) and run setup_tools() again",
    0x29: "the tracker's firmware must be reinstalled: contact NDI support",
    0x2B: "run setup_tools() again: the handle was freed or never allocated",
    0x2C: "the tool was unplugged: plug it back in and run setup_tools() again",
    0x2E: "update the tracker's firmware so that all its components match",
    0x40: "check the tool definition (.rom) file: it is damaged or not a tool definition",
    0x41: "this tool definition does not suit this tracker: use one made for it",
    0x42: "connect the device this command is for, or do not send it",
    0xF1: "shield the camera from sunlight and other infrared sources",
}

#: TX/BX reply options: ``0x0001`` transformations, port status and frame number; ``0x0800``
#: also the transformations the tracker does not normally report, such as those of a tool
#: outside the characterised measurement volume (ndicapi.h NDI_XFORMS_AND_STATUS and
#: NDI_NOT_NORMALLY_REPORTED; sawNDITracker polls ``TX 0801``). The reply's layout is the same.
REPLY_TRANSFORMS = 0x0001
REPLY_ALL_TRANSFORMS = 0x0800

#: Port status bits (TX: 8 hex digits; BX: uint32). Bits 0-7 as in ndicapi.h
#: (NDI_TOOL_IN_PORT ... NDI_PARTIALLY_IN_VOLUME); bits 8-15 as the current API guide lists them
#: (NDI's own ndtrack Python sample, capi/bx.py PortStatus; bits 10, 11 and 13 reserved).
PORT_OCCUPIED = 0x01
PORT_SWITCH_1 = 0x02
PORT_SWITCH_2 = 0x04
PORT_SWITCH_3 = 0x08
PORT_INITIALIZED = 0x10
PORT_ENABLED = 0x20
PORT_OUT_OF_VOLUME = 0x40
PORT_PARTIALLY_IN_VOLUME = 0x80
PORT_ALGORITHM_LIMITATION = 0x0100
PORT_IR_INTERFERENCE = 0x0200
PORT_PROCESSING_EXCEPTION = 0x1000
PORT_FELL_BEHIND = 0x4000
PORT_DATA_BUFFER_LIMITATION = 0x8000

#: Port status bits 8-15: each one set means the tracker's processing of this tool's markers went
#: wrong, so the pose (if any) is refused with the bit's name and what to do about it.
PORT_FAULT_BITS: dict[int, tuple[str, str]] = {
    PORT_ALGORITHM_LIMITATION: (
        "algorithm limitation (processing needs more buffer than the tracker has)",
        "the tracker has too much to process: take stray markers and reflective objects out of "
        "its view, or enable fewer tools",
    ),
    PORT_IR_INTERFERENCE: (
        "IR interference (a large bright infrared object)",
        "remove or cover the bright infrared source in the camera's view (sunlight, a lamp, a "
        "shiny surface)",
    ),
    0x0400: (
        "reserved port status bit 10",
        "the API guide reserves this bit: check the tracker's firmware and its documentation",
    ),
    0x0800: (
        "reserved port status bit 11",
        "the API guide reserves this bit: check the tracker's firmware and its documentation",
    ),
    PORT_PROCESSING_EXCEPTION: (
        "processing exception",
        "the tracker failed to process this frame; if it repeats, power-cycle the tracker",
    ),
    0x2000: (
        "reserved port status bit 13",
        "the API guide reserves this bit: check the tracker's firmware and its documentation",
    ),
    PORT_FELL_BEHIND: (
        "fell behind while processing",
        "the tracker cannot keep up: enable fewer tools or take stray markers out of its view",
    ),
    PORT_DATA_BUFFER_LIMITATION: (
        "data buffer limitation (too much data, e.g. too many markers)",
        "take stray markers and reflective objects out of the camera's view",
    ),
}

PORT_STATUS_BITS: dict[int, str] = {
    PORT_OCCUPIED: "occupied",
    PORT_SWITCH_1: "switch 1 closed / GPIO line 1 active",
    PORT_SWITCH_2: "switch 2 closed / GPIO line 2 active",
    PORT_SWITCH_3: "switch 3 closed / GPIO line 3 active",
    PORT_INITIALIZED: "initialised",
    PORT_ENABLED: "enabled",
    PORT_OUT_OF_VOLUME: "out of volume",
    PORT_PARTIALLY_IN_VOLUME: "partially out of volume",
    **{bit: name for bit, (name, _) in PORT_FAULT_BITS.items()},
}

#: System status bits (TX: 4 hex digits; BX: uint16), as the current API guide lists them (NDI's
#: ndtrack sample, capi/bx.py SystemStatus): bits 0, 3 and 6-10. Bits 1, 2, 4 and 5 are reserved
#: there; older firmware used them as ndicapi.h's NDI_TOO_MUCH_EXTERNAL_INFRARED,
#: NDI_COMM_CRC_ERROR, NDI_HARDWARE_FAILURE and NDI_HARDWARE_CHANGE, which are named too.
SYSTEM_SYNC_ERROR = 0x0001
SYSTEM_PROCESSING_EXCEPTION = 0x0008
SYSTEM_PORT_OCCUPIED = 0x0040
SYSTEM_PORT_UNOCCUPIED = 0x0080
SYSTEM_DIAGNOSTIC_PENDING = 0x0100
SYSTEM_TEMPERATURE = 0x0200
SYSTEM_CONFIGURATION_CHANGED = 0x0400
SYSTEM_STATUS_BITS: dict[int, str] = {
    SYSTEM_SYNC_ERROR: "system communication synchronisation error",
    0x0002: "reserved bit 1 (older firmware: too much external infrared)",
    0x0004: "reserved bit 2 (older firmware: the tracker received a command with a bad CRC)",
    SYSTEM_PROCESSING_EXCEPTION: "recoverable system processing exception",
    0x0010: "reserved bit 4 (older firmware: hardware failure)",
    0x0020: "reserved bit 5 (older firmware: hardware changed)",
    SYSTEM_PORT_OCCUPIED: "a port handle has become occupied",
    SYSTEM_PORT_UNOCCUPIED: "a port handle has become unoccupied",
    SYSTEM_DIAGNOSTIC_PENDING: "diagnostic pending",
    SYSTEM_TEMPERATURE: "the tracker is not within its operating temperature range",
    SYSTEM_CONFIGURATION_CHANGED: "hardware configuration changed",
}

#: What to do about the system status bits that are faults.
SYSTEM_STATUS_HINT: dict[int, str] = {
    0x0002: "shield the camera from sunlight and other infrared sources",
    SYSTEM_PROCESSING_EXCEPTION: "if it repeats, power-cycle the tracker",
    0x0010: "power-cycle the tracker; if it persists, contact NDI support",
    SYSTEM_TEMPERATURE: "its accuracy is specified only within that range (and a tracker "
    "warming up drifts): let it warm up after power-on, keep it out of the sun and draughts, "
    "and record again once the bit clears",
}

#: System status bits that make a frame's poses suspect (a sample from it carries a fault).
#: The communication bits concern earlier exchanges, not this CRC-checked reply: poll() logs
#: them; the port (un)occupied and configuration bits are news, not faults (poll() logs a
#: pending diagnostic and a configuration change).
SYSTEM_FAULT_BITS = 0x0002 | SYSTEM_PROCESSING_EXCEPTION | 0x0010 | SYSTEM_TEMPERATURE
SYSTEM_LINK_BITS = SYSTEM_SYNC_ERROR | 0x0004
SYSTEM_NOTICE_BITS = SYSTEM_DIAGNOSTIC_PENDING | SYSTEM_CONFIGURATION_CHANGED

#: BX handle status byte.
BX_VALID, BX_MISSING, BX_DISABLED = 0x01, 0x02, 0x04

#: A reported quaternion whose norm is further than this from 1 is not a rotation: the reply
#: is refused. The text format's rounding (1e-4 per component) moves the norm by < 2e-4.
QUATERNION_NORM_TOLERANCE = 1e-3

#: The largest position coordinate (mm) a pose may report. No NDI tracker measures beyond a few
#: metres and TX's fields stop at +-9999.99 mm; a larger (finite) BX float is garbage that
#: passed the CRC (100 m leaves room for any tracker and any tracker frame origin).
MAX_POSITION_MM = 1e5

BX_START = b"\xc4\xa5"

# The records of a TX:0001 (or 0801) reply, exactly as specified (fullmatch: nothing more,
# nothing less). DISABLED and UNOCCUPIED come bare or followed by port status and frame number:
# ndicapi.cxx's ndiTXHelper reads status and frame after DISABLED when the line goes on and
# skips the bare word UNOCCUPIED; sawNDITracker's mtsNDISerial::Track skips status and frame
# after both words.
_TX_POSE = re.compile(
    rb"([0-9A-F]{2})([+-]\d{5})([+-]\d{5})([+-]\d{5})([+-]\d{5})"
    rb"([+-]\d{6})([+-]\d{6})([+-]\d{6})([+-]\d{5})([0-9A-F]{8})([0-9A-F]{8})"
)
_TX_MISSING = re.compile(rb"([0-9A-F]{2})MISSING([0-9A-F]{8})([0-9A-F]{8})")
_TX_DISABLED = re.compile(rb"([0-9A-F]{2})DISABLED(?:([0-9A-F]{8})([0-9A-F]{8}))?")
_TX_UNOCCUPIED = re.compile(rb"([0-9A-F]{2})UNOCCUPIED(?:([0-9A-F]{8})([0-9A-F]{8}))?")
_HEX2 = re.compile(rb"[0-9A-F]{2}")
_HEX4 = re.compile(rb"[0-9A-F]{4}")
_PHSR = re.compile(rb"([0-9A-F]{2})((?:[0-9A-F]{5})*)")

# pyserial reads block in slices this long (s), so a reply's deadline is kept to within it
# without reconfiguring the port's timeout (which reprograms the UART on every change).
_READ_SLICE_S = 0.02

#: Bits on the serial line per byte (8N1: start, 8 data, stop).
BITS_PER_BYTE = 10


class _Exchange(NamedTuple):
    """One command and its reply, unchecked, with the host times (monotonic s) around it."""

    raw: bytes
    t_write: float  #: just before the command was handed to the port
    t_sent: float  #: when the port accepted it (write returned)
    t_recv: float  #: when the reply's last byte arrived


# ------------------------------------------------------------------------------------------------
# Errors
# ------------------------------------------------------------------------------------------------
class TrackerError(Exception):
    """Something went wrong talking to the tracker; the message names the port and says what to
    do. ``port`` is the port URL."""

    def __init__(self, message: str, port: str = ""):
        super().__init__(message)
        self.port = port


class TrackerCRCError(TrackerError):
    """A reply failed its CRC (garbled bytes, line noise, a wrong baud rate): it was discarded."""


class TrackerFormatError(TrackerError):
    """A reply passed its CRC but does not follow the documented format: it was discarded."""


class TrackerTimeout(TrackerError):
    """No complete reply in time. ``partial`` holds what did arrive (empty when nothing did)."""

    def __init__(self, message: str, port: str = "", partial: bytes = b""):
        super().__init__(message, port)
        self.partial = partial


class TrackerReplyError(TrackerError):
    """The tracker answered ``ERRORxx``: ``code`` (int) to ``command`` (str)."""

    def __init__(self, message: str, port: str = "", code: int = 0, command: str = ""):
        super().__init__(message, port)
        self.code = code
        self.command = command


class TrackerDisconnected(TrackerError):
    """The port is gone (cable unplugged, adapter removed, tracker off) or cannot be opened."""


def error_text(code: int) -> str:
    """The NDI meaning of an ``ERRORxx`` code, with a hint for the common ones."""
    text = ERROR_TEXT.get(code, "unknown error code (see the NDI API guide)")
    hint = ERROR_HINT.get(code)
    return f"{text}; {hint}" if hint else text


def _preview(data: bytes, limit: int = 48) -> str:
    shown = repr(bytes(data[:limit]))
    return shown + (f"... ({len(data)} bytes)" if len(data) > limit else "")


_NOISE_ADVICE = (
    "the reading was discarded. An occasional one is line noise; if they are frequent, check the "
    "cable (shielded, short, away from motor power) and try a lower baud rate"
)


def _crc_error(port: str, command: str, reply: bytes, why: str) -> TrackerCRCError:
    return TrackerCRCError(
        f"corrupt reply from the tracker on {port} to {command!r}: {why} in {_preview(reply)}; "
        f"{_NOISE_ADVICE}",
        port,
    )


def _format_error(port: str, command: str, reply: bytes, why: str) -> TrackerFormatError:
    return TrackerFormatError(
        f"unexpected reply from the tracker on {port} to {command!r}: {why} in {_preview(reply)}; "
        "the reading was discarded. Check that the device is an NDI Combined API tracker and that "
        "nothing else talks to it on this port",
        port,
    )


def _reply_error(payload: bytes, port: str, command: str) -> TrackerReplyError:
    code_text = payload[5:7]
    code = int(code_text, 16) if _HEX2.fullmatch(code_text) else -1
    return TrackerReplyError(
        f"the tracker on {port} refused {command!r}: {payload[:7].decode('ascii', 'replace')} "
        f"({error_text(code)})",
        port,
        code,
        command,
    )


def checked_payload(reply: bytes, port: str = "", command: str = "") -> bytes:
    """The payload of an ASCII reply (with or without its final CR) once its CRC is checked.

    Raises :class:`TrackerCRCError` when the CRC does not match (or the reply is too short to
    carry one) and :class:`TrackerReplyError` for an ``ERRORxx`` reply.
    """
    body = reply[:-1] if reply[-1:] == b"\r" else reply
    if len(body) < 5:
        raise _crc_error(port, command, reply, "too short to carry a CRC")
    payload, crc_field = body[:-4], body[-4:]
    expected = crc16_hex(payload)
    if crc_field != expected:
        raise _crc_error(
            port,
            command,
            reply,
            f"CRC mismatch (the reply says {crc_field.decode('ascii', 'replace')!r}, "
            f"its content gives {expected.decode()!r})",
        )
    if payload[:5] == b"ERROR":
        raise _reply_error(payload, port, command)
    return payload


def build_command(command: str) -> bytes:
    """The bytes to send for ``command``: ``NAME:params`` gets its CRC appended, then CR."""
    data = command.encode("ascii")
    if b":" in data:
        data += crc16_hex(data)
    return data + b"\r"


# ------------------------------------------------------------------------------------------------
# Frames
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class ToolReport:
    """One port handle in one tracker frame.

    ``state`` is ``"ok"`` (pose present), ``"missing"`` (the tracker does not see the tool),
    ``"disabled"``, or ``"invalid"`` (the tracker sent a pose record with a number no pose can
    have: ``defect`` says which, e.g. "non-finite position (x = nan)"). ``position`` (3,) mm
    and ``quaternion`` (4,) unit, scalar first, are None unless ``ok`` (then every number is
    finite); ``rms_mm`` is the tracker's RMS marker fit error (mm, NaN unless ``ok``).
    ``port_status`` is the bit field of :data:`PORT_STATUS_BITS`; ``frame_number`` the
    tracker's frame counter (None when not reported). A pose whose port status carries one of
    :data:`PORT_FAULT_BITS` is still ``ok`` (the numbers are there), but :meth:`problem` refuses
    it, naming the bits.
    """

    handle: int
    state: Literal["ok", "missing", "disabled", "invalid"]
    position: np.ndarray | None = None
    quaternion: np.ndarray | None = None
    rms_mm: float = math.nan
    port_status: int = 0
    frame_number: int | None = None
    defect: str = ""

    @property
    def visible(self) -> bool:
        return self.state == "ok"

    @property
    def out_of_volume(self) -> bool:
        """The tool is outside the tracker's characterised measurement volume."""
        return bool(self.port_status & PORT_OUT_OF_VOLUME)

    @property
    def partially_out_of_volume(self) -> bool:
        """Some of the tool's markers are outside the characterised volume."""
        return bool(self.port_status & PORT_PARTIALLY_IN_VOLUME)

    @property
    def port_faults(self) -> list[str]:
        """The names of the :data:`PORT_FAULT_BITS` set in :attr:`port_status` (bits 8-15)."""
        return [name for bit, (name, _) in PORT_FAULT_BITS.items() if self.port_status & bit]

    def _fault_bits_text(self) -> tuple[str, str]:
        """(names, what to do) of the port status fault bits set, or ("", "")."""
        set_bits = [(n, h) for bit, (n, h) in PORT_FAULT_BITS.items() if self.port_status & bit]
        names = ", ".join(n for n, _ in set_bits)
        hints = "; ".join(dict.fromkeys(h for _, h in set_bits))
        return names, hints

    def problem(self, port: str = "", accept_out_of_volume: bool = False) -> str | None:
        """A sentence for the operator when this tool's reading must not be used, else None."""
        where = f"the tracker on {port}" if port else "the tracker"
        names, hints = self._fault_bits_text()
        if self.state == "missing":
            cause = f": {names}" if names else ""
            if self.out_of_volume:
                advice = (
                    "It is outside the characterised measurement volume: move the tool back into "
                    "the volume"
                )
            else:
                advice = (
                    "Clear the line of sight between the camera and the tool's markers, or bring "
                    "the tool back into the measurement volume"
                )
            return (
                f"tool {self.handle:02X} MISSING: {where} does not see it (port status "
                f"{self.port_status:08X}{cause}). {advice}" + (f"; {hints}" if hints else "")
            )
        if self.state == "disabled":
            return f"tool {self.handle:02X} is DISABLED on {where}: run setup_tools() to enable it"
        if self.state == "invalid":
            frame = "" if self.frame_number is None else f"tracker frame {self.frame_number}: "
            return (
                f"{frame}{self.defect} of tool {self.handle:02X} from {where}: a number no pose "
                "can have, in a reply that passed its CRC, so that reading was discarded. An "
                "occasional one is a tracker glitch; if it repeats, power-cycle the tracker and "
                "check its firmware"
            )
        problems = []
        if names:
            problems.append(
                f"tool {self.handle:02X} from {where}: port status {self.port_status:08X} reports "
                f"{names}, so that pose was refused. {hints[:1].upper()}{hints[1:]}"
            )
        if not accept_out_of_volume and (self.out_of_volume or self.partially_out_of_volume):
            part = "partly " if not self.out_of_volume else ""
            at = ""
            if self.position is not None:
                x, y, z = (float(c) for c in self.position)
                at = f"at ({x:.1f}, {y:.1f}, {z:.1f}) mm in the tracker's frame; "
            problems.append(
                f"tool {self.handle:02X} is {part}outside the characterised measurement volume "
                f"of {where} ({at}port status {self.port_status:08X}): its pose is not within "
                "the stated accuracy. Move the tool back into the volume (move the robot or the "
                "tracker so that the tool stays inside it)"
            )
        return "; ".join(problems) or None


@dataclass(frozen=True, slots=True)
class UnoccupiedPort:
    """A port handle the tracker reported ``UNOCCUPIED`` in a frame: nothing is plugged into
    that port any more. ``port_status`` and ``frame_number`` are those the record carried
    (0 and None for the bare word)."""

    handle: int
    port_status: int = 0
    frame_number: int | None = None

    def problem(self, port: str = "") -> str:
        """What the operator reads when this handle's pose is asked for."""
        where = f"the tracker on {port}" if port else "the tracker"
        return (
            f"tool {self.handle:02X} is UNOCCUPIED on {where}: nothing is plugged into its port "
            "any more (the tool was unplugged or its cable came loose). Plug it back in, then "
            "run setup_tools() (or reconnect())"
        )


@dataclass(frozen=True, slots=True)
class TrackerFrame:
    """One reply to TX (or BX): every reported handle, the system status, and when it came.

    ``tools`` are the handles with data (a pose, MISSING, DISABLED or an invalid record);
    ``unoccupied`` the handles reported UNOCCUPIED (nothing in that port), which have none.
    ``received_at`` is the host's ``time.monotonic()`` (s) when the reply's last byte arrived;
    ``latency_s`` the time from sending the command to that moment (NaN when parsed offline).
    ``port`` names the port the frame came from (used in messages). ``measured_at`` is the host
    time (``time.monotonic()`` s) at which the tracker measured this frame, as the driver's
    :class:`FrameClock` estimates it from the frame number, and ``timing_uncertainty_s`` the
    half-width (s) of the interval it is known to lie in (both NaN when parsed offline).
    """

    tools: tuple[ToolReport, ...]
    system_status: int
    received_at: float = math.nan
    latency_s: float = math.nan
    port: str = ""
    measured_at: float = math.nan
    timing_uncertainty_s: float = math.nan
    unoccupied: tuple[UnoccupiedPort, ...] = ()

    @property
    def t(self) -> float:
        """The frame's time stamp (monotonic s): ``measured_at`` when known, else
        ``received_at``."""
        return self.measured_at if math.isfinite(self.measured_at) else self.received_at

    @property
    def frame_number(self) -> int | None:
        """The tracker's frame counter (the largest reported by any handle), or None."""
        numbers = [t.frame_number for t in (*self.tools, *self.unoccupied)]
        known = [n for n in numbers if n is not None]
        return max(known) if known else None

    def tool(self, handle: int | None = None) -> ToolReport:
        """The report of ``handle`` (the first handle when None). KeyError, with a sentence for
        the operator, when the frame has no data for it (absent, or UNOCCUPIED)."""
        if handle is not None:
            for t in self.tools:
                if t.handle == handle:
                    return t
            for u in self.unoccupied:
                if u.handle == handle:
                    raise KeyError(u.problem(self.port))
        elif self.tools:
            return self.tools[0]
        if not self.tools:
            empty = "".join(f"; {u.problem(self.port)}" for u in self.unoccupied)
            raise KeyError(f"the frame from {self.port or 'the tracker'} reports no tool{empty}")
        have = ", ".join(f"{t.handle:02X}" for t in self.tools)
        raise KeyError(
            f"the frame from {self.port or 'the tracker'} has no handle {handle:02X} (has {have})"
        )

    def system_problems(self, mask: int = 0xFFFF) -> list[str]:
        """The system status bits set (within ``mask``), as sentences (with what to do for the
        faults)."""
        status = self.system_status & mask
        out = []
        for bit, text in SYSTEM_STATUS_BITS.items():
            if status & bit:
                hint = SYSTEM_STATUS_HINT.get(bit)
                out.append(
                    f"system status {self.system_status:04X} of the tracker on {self.port}: "
                    f"{text}" + (f"; {hint}" if hint else "")
                )
        reserved = status & ~sum(SYSTEM_STATUS_BITS)
        if reserved:
            out.append(
                f"system status {self.system_status:04X} of the tracker on {self.port}: reserved "
                f"bits {reserved:04X} set (not in the current API guide)"
            )
        return out

    def to_sample(
        self, handle: int | None = None, accept_out_of_volume: bool = False
    ) -> TrackerSample:
        """The :class:`~hexcal.acquisition.TrackerSample` of ``handle``: a pose, or a fault,
        stamped :attr:`t` (the frame's measurement instant when the driver estimated it). A pose
        with a fault (port status fault bits, out of volume, a system fault) keeps its numbers
        in the sample, as raw data; the fault refuses it."""
        try:
            tool = self.tool(handle)
        except KeyError as exc:
            return TrackerSample(self.t, None, None, fault=str(exc.args[0]))
        faults = [p for p in (tool.problem(self.port, accept_out_of_volume),) if p]
        faults += self.system_problems(SYSTEM_FAULT_BITS)
        if not tool.visible:
            return TrackerSample(self.t, None, None, fault="; ".join(faults))
        return TrackerSample(
            self.t,
            tool.position,
            tool.quaternion,
            tool.rms_mm,
            fault="; ".join(faults) or None,
        )


def _nonfinite(v: float) -> bool:
    return not math.isfinite(v)


def _values(names: str, values: tuple[float, ...], bad: Callable[[float], bool]) -> str:
    """``"x = nan, z = inf"``: the named values for which ``bad`` holds."""
    return ", ".join(f"{n} = {v:.6g}" for n, v in zip(names.split(), values, strict=True) if bad(v))


def pose_defect(
    position: tuple[float, float, float],
    quaternion: tuple[float, float, float, float],
    rms_mm: float,
) -> str | None:
    """What makes a reported pose record unusable as numbers, or None: NaN or infinity in the
    ``position`` (mm), the ``quaternion`` or the ``rms_mm``, or a position coordinate beyond
    :data:`MAX_POSITION_MM`. (A finite quaternion of the wrong norm is a format error,
    :func:`parse_tx_reply`.)"""
    defects = []
    if not all(map(math.isfinite, position)):
        defects.append(f"non-finite position ({_values('x y z', position, _nonfinite)})")
    elif max(map(abs, position)) > MAX_POSITION_MM:
        far = _values("x y z", position, lambda v: abs(v) > MAX_POSITION_MM)
        defects.append(f"implausible position ({far} mm, beyond +-{MAX_POSITION_MM:g} mm)")
    if not all(map(math.isfinite, quaternion)):
        defects.append(f"non-finite quaternion ({_values('q0 qx qy qz', quaternion, _nonfinite)})")
    if not math.isfinite(rms_mm):
        defects.append(f"non-finite RMS error ({rms_mm})")
    return "; ".join(defects) or None


def _pose_report(
    handle: int,
    q: tuple[float, float, float, float],
    p: tuple[float, float, float],
    rms_mm: float,
    status: int,
    frame: int,
    port: str,
    command: str,
    reply: bytes,
) -> ToolReport:
    """The report of one pose record: ``ok``, or ``invalid`` when a number is unusable."""
    defect = pose_defect(p, q, rms_mm)
    if defect is not None:
        return ToolReport(handle, "invalid", port_status=status, frame_number=frame, defect=defect)
    return ToolReport(
        handle,
        "ok",
        np.array(p, float),
        _unit_quaternion(q, port, command, reply),
        float(rms_mm),
        status,
        frame,
    )


def _unit_quaternion(q: tuple[float, float, float, float], port: str, command: str, reply: bytes):
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise _format_error(port, command, reply, f"quaternion norm {norm:.5f} is not 1")
    return np.array((q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm))


def parse_tx_reply(
    reply: bytes,
    received_at: float = math.nan,
    *,
    port: str = "",
    command: str = "TX:0001",
    latency_s: float = math.nan,
) -> TrackerFrame:
    """Parse a reply to ``TX:0001`` or ``TX:0801`` (one layout, in the module docstring), CRC
    checked.

    ``reply`` is the whole reply, CRC included, with or without its final CR. Raises
    :class:`TrackerCRCError`, :class:`TrackerReplyError` (``ERRORxx``) or
    :class:`TrackerFormatError`; never returns a frame built from a reply that failed a check.
    """
    payload = checked_payload(reply, port, command)
    records = payload[2:].split(b"\n")
    count = payload[:2]
    if not _HEX2.fullmatch(count):
        raise _format_error(port, command, reply, f"handle count {count!r} is not 2 hex digits")
    if len(records) != int(count, 16) + 1:
        raise _format_error(
            port,
            command,
            reply,
            f"{int(count, 16)} handles announced, {len(records) - 1} records sent",
        )
    tools = []
    unoccupied: list[UnoccupiedPort] = []
    for rec in records[:-1]:
        m = _TX_POSE.fullmatch(rec)
        if m is not None:
            h, q0, qx, qy, qz, x, y, z, err, status, frame = m.groups()
            tools.append(
                _pose_report(
                    int(h, 16),
                    (int(q0) * 1e-4, int(qx) * 1e-4, int(qy) * 1e-4, int(qz) * 1e-4),
                    (int(x) * 0.01, int(y) * 0.01, int(z) * 0.01),
                    int(err) * 1e-4,
                    int(status, 16),
                    int(frame, 16),
                    port,
                    command,
                    reply,
                )
            )
            continue
        m = _TX_MISSING.fullmatch(rec)
        if m is not None:
            h, status, frame = m.groups()
            tools.append(
                ToolReport(
                    int(h, 16), "missing", port_status=int(status, 16), frame_number=int(frame, 16)
                )
            )
            continue
        m = _TX_DISABLED.fullmatch(rec)
        if m is not None:
            h, status, frame = m.groups()
            tools.append(
                ToolReport(
                    int(h, 16),
                    "disabled",
                    port_status=int(status, 16) if status else 0,
                    frame_number=int(frame, 16) if frame else None,
                )
            )
            continue
        m = _TX_UNOCCUPIED.fullmatch(rec)
        if m is not None:
            # Nothing in that port: no data, but the other handles' records stand.
            h, status, frame = m.groups()
            unoccupied.append(
                UnoccupiedPort(
                    int(h, 16),
                    int(status, 16) if status else 0,
                    int(frame, 16) if frame else None,
                )
            )
            continue
        raise _format_error(
            port,
            command,
            reply,
            f"handle record {bytes(rec)!r} is not a pose, MISSING, DISABLED or UNOCCUPIED",
        )
    status = records[-1]
    if not _HEX4.fullmatch(status):
        raise _format_error(
            port, command, reply, f"system status {bytes(status)!r} is not 4 hex digits"
        )
    return TrackerFrame(
        tuple(tools), int(status, 16), received_at, latency_s, port, unoccupied=tuple(unoccupied)
    )


def parse_bx_reply(
    reply: bytes,
    received_at: float = math.nan,
    *,
    port: str = "",
    command: str = "BX:0001",
    latency_s: float = math.nan,
) -> TrackerFrame:
    """Parse a binary reply to ``BX:0001`` or ``BX:0801`` (one layout, in the module docstring),
    both CRCs checked.

    An ASCII reply (``ERRORxx``) raises :class:`TrackerReplyError`; otherwise as
    :func:`parse_tx_reply`.
    """
    if reply[:2] != BX_START:
        if reply[-1:] == b"\r":
            checked_payload(reply, port, command)  # raises on ERRORxx or a bad CRC
        raise _crc_error(port, command, reply, "no binary start sequence C4 A5")
    if len(reply) < 8:
        raise _crc_error(port, command, reply, "binary reply cut short")
    length, header_crc = struct.unpack_from("<HH", reply, 2)
    if crc16(reply[:4]) != header_crc:
        raise _crc_error(port, command, reply, "header CRC mismatch")
    if len(reply) != 6 + length + 2:
        raise _crc_error(
            port, command, reply, f"header announces {length} body bytes, {len(reply) - 8} arrived"
        )
    body = reply[6 : 6 + length]
    if crc16(body) != struct.unpack_from("<H", reply, 6 + length)[0]:
        raise _crc_error(port, command, reply, "body CRC mismatch")
    tools = []
    try:
        pos = 1
        for _ in range(body[0]):
            handle, state = body[pos], body[pos + 1]
            pos += 2
            if state == BX_DISABLED:
                tools.append(ToolReport(handle, "disabled"))
                continue
            if state == BX_VALID:
                q0, qx, qy, qz, x, y, z, err = struct.unpack_from("<8f", body, pos)
                pos += 32
                status, frame = struct.unpack_from("<II", body, pos)
                pos += 8
                tools.append(
                    _pose_report(
                        handle,
                        (q0, qx, qy, qz),
                        (x, y, z),
                        err,
                        status,
                        frame,
                        port,
                        command,
                        reply,
                    )
                )
            elif state == BX_MISSING:
                status, frame = struct.unpack_from("<II", body, pos)
                pos += 8
                tools.append(ToolReport(handle, "missing", port_status=status, frame_number=frame))
            else:
                raise _format_error(
                    port, command, reply, f"handle {handle:02X} has status byte {state:02X}"
                )
        (system_status,) = struct.unpack_from("<H", body, pos)
        pos += 2
    except (IndexError, struct.error):
        raise _format_error(port, command, reply, "body shorter than its handle records") from None
    if pos != len(body):
        raise _format_error(
            port, command, reply, f"{len(body) - pos} unexpected bytes after the system status"
        )
    return TrackerFrame(tuple(tools), system_status, received_at, latency_s, port)


def parse_phsr_reply(
    payload: bytes, port: str = "", command: str = "PHSR"
) -> list[tuple[int, int]]:
    """(handle, handle status) pairs of a checked PHSR payload."""
    m = _PHSR.fullmatch(payload)
    if m is None or len(m.group(2)) != 5 * int(m.group(1), 16):
        raise _format_error(port, command, payload, "not a PHSR handle list")
    entries = m.group(2)
    return [
        (int(entries[i : i + 2], 16), int(entries[i + 2 : i + 5], 16))
        for i in range(0, len(entries), 5)
    ]


# ------------------------------------------------------------------------------------------------
# Frame clock
# ------------------------------------------------------------------------------------------------
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


# ------------------------------------------------------------------------------------------------
# The driver
# ------------------------------------------------------------------------------------------------
class NDITracker:
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

    Timing (see :class:`FrameClock` and the module docstring): ``frame_rate_hz`` is the
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
        self.max_jitter_s = check_duration("max_jitter_s", max_jitter_s)
        self.resync_s = check_duration("resync_s", resync_s, allow_zero=True)
        self.port: serial.SerialBase | None = None
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
                self.port = serial.serial_for_url(
                    self.url, baudrate=9600, timeout=_READ_SLICE_S, write_timeout=self.timeout
                )
            except (ValueError, *_IO_ERRORS) as exc:
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

    def __enter__(self) -> NDITracker:
        if self.port is None:
            self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

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

    def _stamp(self, frame: TrackerFrame, command: str, ex: _Exchange) -> TrackerFrame:
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
        :attr:`pose_handle`: the acquisition's :class:`~hexcal.acquisition.PoseSource`.

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
            if self.timing_warning is None:
                self.timing_warning = (
                    f"the tracker on {self.url} answers with an irregular delay: "
                    f"{st['min_s'] * 1e3:.1f} to {st['max_s'] * 1e3:.1f} ms over the last {st['n']} "
                    f"polls (jitter {st['spread_s'] * 1e3:.1f} ms > {self.max_jitter_s * 1e3:.0f} ms), "
                    "so host receive times are uncertain by that much. Samples are stamped from the "
                    "tracker's frame numbers (clock_stats()), which this does not upset, but check "
                    "the host load or the USB hub/adapter"
                )
                log.warning(self.timing_warning)
        elif st["spread_s"] < 0.5 * self.max_jitter_s:
            self.timing_warning = None

    # -- the wire -------------------------------------------------------------------------------
    def _require_port(self) -> serial.SerialBase:
        if self.port is None:
            raise TrackerDisconnected(
                f"the tracker on {self.url} is not open: call open() first", self.url
            )
        if self._dead:
            raise TrackerDisconnected(
                f"the connection to the tracker on {self.url} was lost: plug it back in, then call reconnect()",
                self.url,
            )
        return self.port

    def _lost(self, exc: BaseException) -> TrackerDisconnected:
        self._dead = True
        # reconnect() must resume tracking: the loss, not the operator, ended it.
        self._resume_tracking = self._resume_tracking or self.tracking
        self.tracking = False
        return TrackerDisconnected(
            f"lost the connection to the tracker on {self.url} ({exc}): the cable or USB adapter was "
            "unplugged or the tracker was switched off. Plug it back in on the same port, then call "
            "reconnect()",
            self.url,
        )

    def _exchange(self, command: str, timeout: float, binary: bool = False) -> _Exchange:
        """Send ``command``; return the raw reply, unchecked, and the host times around it."""
        port = self._require_port()
        data = build_command(command)
        try:
            if self._resync:
                self._drain(port, self.resync_s)
            # Anything unread is left over from a failed exchange (ndicapi does the same).
            port.reset_input_buffer()
            t_write = time.monotonic()  # the command cannot reach the tracker before this
            port.write(data)
            t_sent = time.monotonic()
            deadline = t_sent + timeout
            raw = (
                self._read_binary(port, command, deadline)
                if binary
                else self._read_line(port, command, deadline)
            )
            return _Exchange(raw, t_write, t_sent, time.monotonic())
        except serial.SerialTimeoutException as exc:
            raise TrackerTimeout(
                f"could not send {command!r} to the tracker on {self.url} within {self.timeout:g} s "
                f"({exc}): check the cable and handshake settings",
                self.url,
            ) from exc
        except TrackerTimeout:
            self._resync = True
            raise
        except _IO_ERRORS as exc:
            raise self._lost(exc) from exc

    def _drain(self, port: serial.SerialBase, duration: float) -> None:
        """Read and discard for ``duration`` s (a late reply to a command that timed out)."""
        end = time.monotonic() + duration
        dropped = 0
        while time.monotonic() < end:
            dropped += len(port.read(max(1, port.in_waiting)))
        if dropped:
            log.info("tracker on %s: discarded %d late bytes", self.url, dropped)
        self._resync = False

    def _timeout(self, command: str, buf: bytes, waited: float) -> TrackerTimeout:
        if not buf:
            msg = (
                f"no reply from the tracker on {self.url} to {command!r} within {waited:g} s: check "
                "that it is switched on and connected, and that nothing else uses the port"
            )
        else:
            msg = (
                f"incomplete reply from the tracker on {self.url} to {command!r}: {len(buf)} bytes "
                f"then nothing for {waited:g} s ({_preview(buf)}); the reply was cut off or bytes "
                "were lost, so it was discarded. If it persists check the cable and the baud rate"
            )
        return TrackerTimeout(msg, self.url, bytes(buf))

    def _read_line(
        self, port: serial.SerialBase, command: str, deadline: float, buf: bytearray | None = None
    ) -> bytes:
        buf = bytearray() if buf is None else buf
        start = time.monotonic()
        while True:
            chunk = port.read(max(1, port.in_waiting))
            if chunk:
                buf += chunk
                end = buf.find(b"\r")
                if end >= 0:
                    # The tracker speaks only when asked: bytes after the CR are noise, dropped
                    # by the next exchange's flush.
                    return bytes(buf[: end + 1])
            if time.monotonic() >= deadline:
                raise self._timeout(command, buf, round(deadline - start, 3))

    def _read_exact(
        self,
        port: serial.SerialBase,
        n: int,
        buf: bytearray,
        command: str,
        deadline: float,
        start: float,
    ) -> None:
        while len(buf) < n:
            chunk = port.read(min(n - len(buf), max(1, port.in_waiting)))
            buf += chunk
            if not chunk and time.monotonic() >= deadline:
                raise self._timeout(command, buf, round(deadline - start, 3))

    def _read_binary(self, port: serial.SerialBase, command: str, deadline: float) -> bytes:
        buf = bytearray()
        start = time.monotonic()
        self._read_exact(port, 2, buf, command, deadline, start)
        if bytes(buf[:2]) != BX_START:  # an ASCII reply (ERRORxx) or noise: read it to its CR
            if b"\r" in buf:
                return bytes(buf[: buf.find(b"\r") + 1])
            return self._read_line(port, command, deadline, buf)
        self._read_exact(port, 6, buf, command, deadline, start)
        (length,) = struct.unpack_from("<H", buf, 2)
        # A garbled length must not make us wait for 64 kB: the header CRC decides first.
        if crc16(buf[:4]) != struct.unpack_from("<H", buf, 4)[0]:
            return bytes(buf)  # parse_bx_reply reports the header CRC error
        self._read_exact(port, 6 + length + 2, buf, command, deadline, start)
        return bytes(buf)

    def _set_baud(self, baud: int) -> None:
        port = self._require_port()
        try:
            if port.baudrate != baud:
                port.baudrate = baud
        except (ValueError, *_IO_ERRORS) as exc:
            raise self._lost(exc) from exc

    def _reset_tracker(self) -> None:
        """Reset the tracker to 9600 baud, by BREAK and/or the RESET command (see ``reset``)."""
        tried = []
        if self.reset in ("break", "auto"):
            tried.append("a serial BREAK at 9600 baud")
            if self._try_reset(None):
                return
        if self.reset in ("command", "auto"):
            # At 9600 (fresh tracker), at the working rate (left there by a session that could
            # not close), then at 9600 again: whether a tracker reset at another rate answers at
            # that rate or at 9600 is not documented, so both are covered.
            bauds = (9600,) if self.baudrate == 9600 else (9600, self.baudrate, 9600)
            for baud in bauds:
                tried.append(f"RESET:0 at {baud} baud")
                if self._try_reset(baud):
                    self._set_baud(9600)
                    return
        self._set_baud(9600)
        raise TrackerTimeout(
            f"the tracker on {self.url} did not answer RESETBE6F to {' nor '.join(tried)} "
            f"(waited {self.reset_timeout_s:g} s each): check that it is switched on, that this is "
            "its port and that the cable is a straight-through serial cable"
            + (
                "; a pty or network bridge cannot carry a BREAK, use reset='command' or 'auto'"
                if self.reset == "break"
                else ""
            ),
            self.url,
        )

    def _try_reset(self, baud: int | None) -> bool:
        """One reset attempt: a BREAK (baud None) or RESET:0 sent at ``baud``."""
        port = self._require_port()
        command = "RESET:0" if baud is not None else "BREAK"
        try:
            self._set_baud(9600 if baud is None else baud)
            port.reset_input_buffer()
            if baud is None:
                port.send_break(self.break_duration_s)
            else:
                port.write(build_command(command))
            reply = self._read_line(port, command, time.monotonic() + self.reset_timeout_s)
        except TrackerTimeout as exc:
            log.info("tracker on %s: no answer to %s (%s)", self.url, command, exc)
            return False
        except _IO_ERRORS as exc:
            raise self._lost(exc) from exc
        if reply.endswith(b"RESETBE6F\r"):
            return True
        log.info("tracker on %s: unexpected answer to %s: %s", self.url, command, _preview(reply))
        return False

    def _close_port(self) -> None:
        port, self.port = self.port, None
        if port is not None:
            try:
                port.close()
            except _IO_ERRORS as exc:  # closing a vanished port: nothing left to do
                log.debug("closing %s: %s", self.url, exc)
