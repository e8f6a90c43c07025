"""The pose block file: records written a group at a time and read back bit for bit, the
header written last, the limit refused as rows arrive, damage named."""

from __future__ import annotations

import numpy as np
import pytest

from hexcal.io.pose_block import (
    HEADER_BYTES,
    PoseBlockError,
    PoseBlockWriter,
    block_dtype,
    decode_texts,
    read_block,
)


def _rows(rng, k: int, start: int):
    pose_id = np.arange(start, start + k)
    q = rng.normal(size=(k, 4))
    return (
        pose_id,
        rng.normal(size=k) * 1e3,
        rng.integers(0, 7, k),
        rng.normal(size=(k, 3)),
        q / np.linalg.norm(q, axis=1, keepdims=True),
        rng.normal(size=(k, 6)),
        rng.normal(size=k),
        [[f"s{i % 3}" for i in pose_id], ["free"] * k, [str(i) for i in pose_id]],
    )


def test_records_round_trip_bit_for_bit_and_numpy_reads_the_file(tmp_path):
    rng = np.random.default_rng(3)
    w = PoseBlockWriter(tmp_path / "s.json", ["step", "constraint", "note"], 100, RuntimeError)
    parts = [_rows(rng, 7, 1), _rows(rng, 5, 8)]
    for p in parts:
        w.add(*p)
    info = w.finish()
    path = tmp_path / info.name
    assert info.poses == 12 and info.name == f"s.json.{info.sha256[:12]}.poses.npy"
    assert info.texts["step"] == ["s1", "s2", "s0"] and info.texts["note"][:2] == ["1", "2"]
    assert path.stat().st_size == HEADER_BYTES + 12 * block_dtype(3).itemsize
    rec = read_block(path, 12, info.sha256, 3)
    assert np.array_equal(np.load(path, allow_pickle=False), rec)
    for field, k in (("pose_id", 0), ("t", 1), ("position", 3), ("readings", 5)):
        assert np.array_equal(rec[field], np.concatenate([p[k] for p in parts]))
    steps = decode_texts(path, rec["texts"][:, 0], info.texts["step"], "step")
    assert steps.tolist() == [f"s{i % 3}" for i in range(1, 13)]
    assert [p.name for p in tmp_path.iterdir()] == [info.name]  # no temporary file left


def test_rows_beyond_the_limit_are_refused_as_they_arrive_and_nothing_is_left(tmp_path):
    rng = np.random.default_rng(4)
    w = PoseBlockWriter(
        tmp_path / "s.json", ["step", "constraint", "note"], 10, lambda: ValueError("past 10")
    )
    w.add(*_rows(rng, 6, 1))
    with pytest.raises(ValueError, match="past 10"):
        w.add(*_rows(rng, 6, 7))
    assert list(tmp_path.iterdir()) == []


def test_a_code_without_its_value_is_damage(tmp_path):
    with pytest.raises(PoseBlockError, match="a code of column 'step' has no value"):
        decode_texts(tmp_path / "b.poses.npy", np.array([0, 2], np.uint32), ["a", "b"], "step")
