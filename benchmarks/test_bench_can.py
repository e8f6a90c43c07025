"""Throughput of the CAN leg-encoder decode path (pytest-benchmark); run with

    python -m pytest benchmarks/test_bench_can.py --benchmark-only

The target: ten times a saturated 1 Mbit/s classical CAN bus (about 8,000 frames/s), i.e.
80,000 frames/s on one core. Each benchmark stores its rate in ``extra_info`` (frames_per_s and
the multiple of a saturated bus); see them with ``--benchmark-json``. No wall-clock assertion.
"""

from __future__ import annotations

import can
import numpy as np
import pytest

from hexcal.drivers.can_config import CanBusConfig, LegEncoderConfig
from hexcal.drivers.can_encoders import LegEncoders, TpdoDecoder, decode_tpdo

SATURATED_BUS_FRAMES_PER_S = 8_000
N_SYNC = 10_000  # 60,000 position TPDO frames per round

CONFIG = CanBusConfig(
    channel="bench",
    legs=[
        LegEncoderConfig(
            leg=k, node_id=0x20 + k, counts_per_mm=1000.0 * k, sign=(-1) ** k, zero_mm=10.0 * k
        )
        for k in range(1, 7)
    ],
)


def _record(benchmark, n_frames: int) -> None:
    rate = n_frames / benchmark.stats.stats.mean
    benchmark.extra_info["frames_per_s"] = round(rate)
    benchmark.extra_info["x_saturated_1mbit_bus"] = round(rate / SATURATED_BUS_FRAMES_PER_S, 1)


@pytest.fixture(scope="module")
def counts() -> np.ndarray:
    """(N_SYNC, 6) INTEGER32 positions."""
    return np.random.default_rng(0).integers(-(2**31), 2**31, (N_SYNC, 6))


@pytest.fixture(scope="module")
def tpdo_frames(counts) -> list[can.Message]:
    return [
        can.Message(
            arbitration_id=0x2A0 + k + 1,
            data=int(c).to_bytes(4, "little", signed=True),
            is_extended_id=False,
        )
        for row in counts
        for k, c in enumerate(row)
    ]


def test_bench_decode_tpdo(benchmark, tpdo_frames):
    """decode_tpdo, one frame at a time (the function the driver's receive thread uses)."""
    dec = TpdoDecoder(CONFIG)

    def run() -> None:
        for msg in tpdo_frames:
            decode_tpdo(msg, dec)

    benchmark(run)
    _record(benchmark, len(tpdo_frames))


def test_bench_decode_batch(benchmark, counts):
    """TpdoDecoder.decode_batch on arrays (log analysis, replays)."""
    dec = TpdoDecoder(CONFIG)
    ids = np.tile(np.arange(0x2A1, 0x2A7), N_SYNC)
    payload = np.zeros((ids.size, 8), np.uint8)
    payload[:, :4] = counts.reshape(-1).astype("<i4").view(np.uint8).reshape(-1, 4)
    legs, mm = benchmark(dec.decode_batch, ids, payload)
    assert np.all(legs > 0) and np.all(np.isfinite(mm))
    _record(benchmark, ids.size)


def test_bench_driver_receive_path(benchmark, tpdo_frames):
    """The whole receive path of LegEncoders: stamp, decode, assemble six positions per SYNC
    into reading sets (SYNC frames included in the count)."""
    sync = can.Message(arbitration_id=0x80, data=[1], is_extended_id=False)
    stream = []
    for i in range(N_SYNC):
        stream.append(sync)
        stream.extend(tpdo_frames[6 * i : 6 * i + 6])

    def fresh():
        # Listen-only and never started: nothing is sent, the bus is never opened.
        return (LegEncoders(CONFIG, listen_only=True),), {}

    def run(drv: LegEncoders) -> None:
        for msg in stream:
            drv._on_message(msg)

    benchmark.pedantic(run, setup=fresh, rounds=5, iterations=1)
    _record(benchmark, len(stream))
