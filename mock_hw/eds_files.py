"""The object dictionaries of the mock encoders beside hexcal's generic one (``mock_hw/eds/``).

Each was written from the CiA 301 and CiA 406 object lists as encoder manuals tabulate them,
not from hexcal's generic EDS (``src/hexcal/data/cia406_encoder.eds``), so that the driver meets
devices it was not written against:

- ``minimal``: a class C1 multi-turn rotary encoder with two TPDOs whose communication records
  hold sub-indices 0..2 only, a fixed (read-only) mapping of 0x6004 in both, an UNSIGNED32
  position, no 0x1019, no 0x6005, an identity with the vendor ID only;
- ``vendor``: a multi-turn rotary encoder with an INTEGER32 position, four TPDOs (sub-indices
  1, 2, 3, 5, 6), a manufacturer area 0x2000..0x2102, 0x1019, and its own EDS stored at 0x1021;
- ``linear``: an absolute linear encoder (device type 0x00080196) with a 5 µm measuring step
  (0x6005 sub-index 1 = 5000 nm), four TPDOs without sub-index 6 whose COB-IDs forbid RTR (bit
  30), every TPDO asynchronous at the factory, node guarding beside the heartbeat, no 0x1019.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

#: name → file in mock_hw/eds/.
MOCK_EDS = {
    "minimal": "minimal_406.eds",
    "vendor": "vendor_rotary_406.eds",
    "linear": "linear_406.eds",
}


def mock_eds(name: str) -> Path:
    """The path of mock EDS ``name`` (a key of :data:`MOCK_EDS`)."""
    if name not in MOCK_EDS:
        raise KeyError(f"no mock EDS {name!r}; there are {', '.join(MOCK_EDS)}")
    ref = resources.files("hexcal.mock_hw").joinpath("eds").joinpath(MOCK_EDS[name])
    with resources.as_file(ref) as p:
        return Path(p)


__all__ = ["MOCK_EDS", "mock_eds"]
