"""Keeps benchmarks/soak.py from rotting: a 2 s soak of the mock rig at the default 10 ms SYNC.

Only correctness is asserted (no frame lost, the set index never skips, every set read, no CRC
error), never a speed or a timing share: those depend on the machine.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

SOAK = Path(__file__).resolve().parents[1] / "benchmarks" / "soak.py"


def _load_soak() -> ModuleType:
    spec = importlib.util.spec_from_file_location("hexcal_bench_soak", SOAK)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is built
    spec.loader.exec_module(module)
    return module


def test_soak_smoke_drops_nothing() -> None:
    soak = _load_soak()
    cfg = soak.SoakConfig(seconds=2.0, sample_period_s=0.5, record_period_s=0.8, trace=False)
    out = soak.run_soak(cfg)
    can, trk, checks = out["can"], out["tracker"], out["verdict"]["checks"]

    assert can["sets_read"] > 0 and trk["new_frames_seen"] > 0
    assert can["tpdo_frames_lost"] == 0 and can["tpdo_frames_received_driver"] > 0
    assert can["index_gaps"] == 0 and can["index_first"] == 0
    assert can["index_last"] == can["sets_driver"] - 1
    assert can["sets_read"] == can["sets_driver"] == can["sync_sent_driver"]
    assert can["discarded_driver"] == 0
    assert can["error_frames"] == 0 and can["bus_state"] == "ACTIVE"
    assert trk["crc_errors"] == 0 and trk["format_errors"] == 0
    assert trk["frames_backwards"] == 0
    assert checks["can_no_frame_lost (every TPDO the mock sent reached the driver)"]
    assert checks["can_index_never_skips"]
    assert checks["can_every_sync_reached_the_mock (seen, or still queued at stop)"]
    assert out["acquisition"]["record_attempts"] >= 1
    assert len(out["memory"]["series"]) >= 3
