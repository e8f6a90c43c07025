"""The NDI Combined API's code tables: baud codes, ``ERRORxx`` texts and hints, reply options,
port and system status bits, and the limits a pose record must respect. What each one means to
the operator is in ``docs/ndi.md``; :mod:`hexcal.drivers.ndi` re-exports every name."""

from __future__ import annotations

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

#: Bits on the serial line per byte (8N1: start, 8 data, stop).
BITS_PER_BYTE = 10
