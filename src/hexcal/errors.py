"""hexcal's exceptions: one hierarchy, whose every message is meant for the operator — it names
the file, line, field or device and says what to do.

- :class:`HexcalError` — the base; the command line prints its message as it is (exit 2, or 3
  for a refusal) and never calls it an internal error.
- :class:`InputError` — a file, field or value given to hexcal is wrong (also a ``ValueError``).
- :class:`DeviceError` — a device (tracker, encoders, motion controller) cannot deliver.
- :class:`RefusedError` — the data do not support what was asked (a calibration, a pose, a fit,
  a prediction); nothing is wrong with the files, more or other poses are needed.
- :class:`MismatchError` — the data disagree with the drawing or with themselves (a unit, a
  sign, the quaternion order, swapped legs, an offset): an input error the command line gives
  exit status 4, as it does a calibration that does not match the drawing.

Each module's own errors derive from one of these (``RobotFileError(InputError)``,
``TrackerTimeout(DeviceError)``, ``CalibrationRefused(RefusedError)``...), so a caller can catch
as finely or as broadly as it needs.
"""

from __future__ import annotations


class HexcalError(Exception):
    """An error hexcal explains: the message names what went wrong and says what to do."""


class InputError(HexcalError, ValueError):
    """A file, field or value given to hexcal is wrong; the message names the file, line and
    field, and says what to fix."""


class DeviceError(HexcalError):
    """A device cannot deliver; the message names the device (port, bus, node) and what to
    check."""


class RefusedError(HexcalError):
    """The data do not support what was asked (a calibration, a pose, a fit, a prediction); the
    message says which poses or motions would."""


class MismatchError(InputError):
    """The data disagree with the drawing or among themselves; the message names the cause
    (units, a sign, the quaternion order, swapped legs, an offset) and the fix."""


__all__ = ["DeviceError", "HexcalError", "InputError", "MismatchError", "RefusedError"]
