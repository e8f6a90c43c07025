"""Throughput of the NDI tracker reply parsers (pytest-benchmark); run with

    python -m pytest benchmarks/test_bench_ndi.py --benchmark-only

The target: ten times what the fastest serial line the API offers can carry. At 921600 baud
(8N1: 10 bits per byte) that is 92,160 bytes/s, so the parser must take at least 921,600 bytes/s
of replies on one core. Each benchmark stores its rate in ``extra_info`` (bytes_per_s,
replies_per_s and the multiple of a saturated 921600-baud line); see them with
``--benchmark-json`` or ``--benchmark-columns``. No wall-clock assertion anywhere.
"""

from __future__ import annotations

import numpy as np
import pytest

from hexcal.drivers.crc import crc16
from hexcal.drivers.ndi import parse_bx_reply, parse_tx_reply
from hexcal.mock_hw.ndi_tracker import ToolState, format_bx_reply, format_tx_reply

LINE_BYTES_PER_S = 921_600 / 10  # 921600 baud, 8N1
N_REPLIES = 5_000


def _replies(n_tools: int, formatter, n: int = N_REPLIES) -> list[bytes]:
    """``n`` distinct replies with ``n_tools`` tools (the last one MISSING when n_tools > 1)."""
    rng = np.random.default_rng(0)
    out = []
    for i in range(n):
        tools = []
        for h in range(1, n_tools + 1):
            if n_tools > 1 and h == n_tools:
                tools.append(ToolState(h, None, 0x31, i))
                continue
            q = rng.normal(size=4)
            q /= np.linalg.norm(q)  # uniform on the unit sphere: a random rotation
            p = rng.uniform(-1500, 1500, 3)
            tools.append(ToolState(h, (p, q, float(rng.uniform(0, 0.5))), 0x31, i))
        out.append(formatter(tools))
    return out


def _record(benchmark, replies: list[bytes]) -> None:
    mean = benchmark.stats.stats.mean
    nbytes = sum(len(r) for r in replies)
    benchmark.extra_info["bytes_per_s"] = round(nbytes / mean)
    benchmark.extra_info["replies_per_s"] = round(len(replies) / mean)
    benchmark.extra_info["x_921600_baud_line"] = round(nbytes / mean / LINE_BYTES_PER_S, 1)


@pytest.mark.parametrize("n_tools", [1, 4])
def test_bench_parse_tx_reply(benchmark, n_tools):
    """parse_tx_reply (CRC check, field validation, floats, unit quaternion), one reply at a
    time as NDITracker.poll calls it: one tool (81 bytes) and four tools, one MISSING."""
    replies = _replies(n_tools, format_tx_reply)

    def run() -> None:
        for r in replies:
            parse_tx_reply(r, 0.0, port="bench")

    benchmark(run)
    _record(benchmark, replies)


def test_bench_parse_bx_reply(benchmark):
    """parse_bx_reply on one-tool binary replies (header and body CRCs, float32 unpacking)."""
    replies = _replies(1, format_bx_reply)

    def run() -> None:
        for r in replies:
            parse_bx_reply(r, 0.0, port="bench")

    benchmark(run)
    _record(benchmark, replies)


def test_bench_crc16(benchmark):
    """The CRC-16/ARC loop alone, on the same bytes as the one-tool TX benchmark."""
    replies = _replies(1, format_tx_reply)

    def run() -> None:
        for r in replies:
            crc16(r)

    benchmark(run)
    _record(benchmark, replies)
