"""A fingerprint of a table's poses by their values — position, orientation, readings — not
their ids or times, so that ``hexcal validate`` knows the poses a model was fitted on in any
copy of them (re-numbered, re-timed, re-ordered, merged with new poses), and knows a different
session as different even when it numbers and times its poses the same (1..N at t = 1, 2, …).

Each pose's key is a 48-bit digest (BLAKE2b) of its twelve values on a grid — the position and
the six readings in steps of :data:`QUANTUM_MM`, the orientation's rotation vector in steps of
:data:`QUANTUM_RAD` — and the fingerprint is the sorted list of keys: order-independent, so a
copy in another order is the same poses and a table holding some of them says how many. A value
copied through another program can differ in its last bits (a unit conversion, a float printed
with 15 digits) and so fall on the other side of a grid step; each pose therefore has a second
key on the grid shifted by half a step, where no value lying near a step of the first grid
lies near a step (a pose is missed only when values sit within the copying error of a step on
both grids: at 10⁻⁹ mm of error, about 10⁻¹⁰ per pose). The steps sit at an irrational
fraction of the grid (:data:`OFFSET`): readings an encoder gives in whole steps of 0.1 or
0.5 µm would otherwise lie exactly on a step of one grid or the other. The steps are far below any real
session's noise (a tracker's 5–50 µm, an encoder's ≥ 1 µm), so two sessions share a key only by
sharing a pose's values.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from hexcal.io.measurements import Measurements

#: Grid step of positions and readings, mm.
QUANTUM_MM = 1e-3
#: Grid step of the orientation's rotation vector, rad (1 µm at 1 m).
QUANTUM_RAD = 1e-6
#: Hex characters of a pose's key (48 bits: two sessions of 10⁴ poses share a key by chance
#: with probability 4·10⁻⁷).
KEY_HEX = 12
#: Where the grid's steps sit, in steps: an irrational fraction (√5 − 2), so that values an
#: instrument gives on a decimal grid (0.1 µm, 0.5 µm …) never sit on a step.
OFFSET = 5**0.5 - 2.0


@dataclass(frozen=True)
class Fingerprint:
    """The poses' keys on the grid (``keys``) and on the grid shifted by half a step
    (``shifted``), each a sorted list of hex strings."""

    keys: list[str]
    shifted: list[str]


def _cells(values: np.ndarray, shift: float) -> np.ndarray:
    # The table's values are finite (hexcal.io.measurements refuses others).
    return np.floor(values + shift).astype("<i8")


def _keys(cells: np.ndarray) -> list[str]:
    n = KEY_HEX // 2
    return [hashlib.blake2b(row.tobytes(), digest_size=n).hexdigest() for row in cells]


def _scaled_values(meas: Measurements) -> np.ndarray:
    """(N, 12): position (mm), rotation vector (rad), readings (mm), each over its grid step."""
    rotvec = meas.rotations.as_rotvec()
    return np.column_stack(
        [
            np.asarray(meas.position, float) / QUANTUM_MM,
            rotvec / QUANTUM_RAD,
            np.asarray(meas.readings, float) / QUANTUM_MM,
        ]
    )


def pose_keys(meas: Measurements) -> tuple[list[str], list[str]]:
    """Each row's key on the grid and on the shifted grid (two lists of N hex strings, in the
    table's order)."""
    v = _scaled_values(meas)
    return _keys(_cells(v, OFFSET)), _keys(_cells(v, OFFSET + 0.5))


def fingerprint(meas: Measurements) -> Fingerprint:
    """The fingerprint of the measurement table ``meas`` (see the module docstring)."""
    keys, shifted = pose_keys(meas)
    return Fingerprint(sorted(set(keys)), sorted(set(shifted)))


def shared_rows(meas: Measurements, fp: Fingerprint) -> np.ndarray:
    """(N,) bool: which rows of ``meas`` are among the poses ``fp`` fingerprints."""
    keys, shifted = pose_keys(meas)
    on, on_shifted = set(fp.keys), set(fp.shifted)
    return np.array(
        [k in on or s in on_shifted for k, s in zip(keys, shifted, strict=True)], dtype=bool
    )
