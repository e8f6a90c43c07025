"""hexcal: calibrate Gough-Stewart platforms from leg-mobility constraints.

Units are millimetres, seconds and degrees Celsius throughout; quaternions in files are unit and
scalar first (``qw, qx, qy, qz``); every rotation goes through
:class:`scipy.spatial.transform.Rotation`.

The public API, by stage of the data flow (example in ``docs/library.md``)::

    robot.json, measurements.csv, instruments.json
        load_robot, read_measurements, load_instruments, import_log
    → calibrate (Model 36 / 42, effects)          → Calibration
    → diagnose (what is missing)                  → Diagnosis
    → calibrated.json: save_model, load_model     → CalibratedRobot, LegModel (predict)
    the vocabulary: Constraint, ModelKind, Outcome (their values are the files' strings)

The names are loaded on first use, so ``import hexcal`` stays quick.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

#: public name → the module that defines it
_HOMES = {
    "Robot": "hexcal.model.robot",
    "load_robot": "hexcal.estimate.model_file",
    "save_robot": "hexcal.model.robot",
    "Measurements": "hexcal.io.measurements",
    "read_measurements": "hexcal.io.measurements_csv",
    "write_measurements": "hexcal.io.measurements",
    "Instruments": "hexcal.model.instruments",
    "load_instruments": "hexcal.model.instruments",
    "save_instruments": "hexcal.model.instruments",
    "import_log": "hexcal.io.log_import",
    "calibrate": "hexcal.estimate.calibrate",
    "Calibration": "hexcal.estimate.calibrate",
    "diagnose": "hexcal.diagnosis.diagnose",
    "Diagnosis": "hexcal.diagnosis.diagnose",
    "CalibratedRobot": "hexcal.estimate.model_file",
    "load_model": "hexcal.estimate.model_file",
    "save_model": "hexcal.estimate.model_file",
    "LegModel": "hexcal.estimate.predict",
    "Constraint": "hexcal.vocabulary",
    "ModelKind": "hexcal.vocabulary",
    "Outcome": "hexcal.vocabulary",
}

__all__ = [
    "CalibratedRobot",
    "Calibration",
    "Constraint",
    "Diagnosis",
    "Instruments",
    "LegModel",
    "Measurements",
    "ModelKind",
    "Outcome",
    "Robot",
    "__version__",
    "calibrate",
    "diagnose",
    "import_log",
    "load_instruments",
    "load_model",
    "load_robot",
    "read_measurements",
    "save_instruments",
    "save_model",
    "save_robot",
    "write_measurements",
]

if TYPE_CHECKING:
    from hexcal.diagnosis.diagnose import Diagnosis, diagnose
    from hexcal.estimate.calibrate import Calibration, calibrate
    from hexcal.estimate.model_file import CalibratedRobot, load_model, load_robot, save_model
    from hexcal.estimate.predict import LegModel
    from hexcal.io.log_import import import_log
    from hexcal.io.measurements import Measurements, write_measurements
    from hexcal.io.measurements_csv import read_measurements
    from hexcal.model.instruments import Instruments, load_instruments, save_instruments
    from hexcal.model.robot import Robot, save_robot
    from hexcal.vocabulary import Constraint, ModelKind, Outcome


def __getattr__(name: str) -> Any:
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module 'hexcal' has no attribute {name!r}")
    value = getattr(importlib.import_module(home), name)
    globals()[name] = value  # once loaded, a plain attribute
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_HOMES})
