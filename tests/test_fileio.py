"""Atomic writes: no temporary file left behind, a new file gets the umask's mode, an existing
file keeps its own."""

from __future__ import annotations

import os

from hexcal.fileio import write_text_atomic


def test_new_file_mode_follows_umask(tmp_path):
    old = os.umask(0o022)
    try:
        write_text_atomic(tmp_path / "a.txt", "x")
    finally:
        os.umask(old)
    assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o644
    assert [p.name for p in tmp_path.iterdir()] == ["a.txt"]


def test_existing_mode_kept(tmp_path):
    p = tmp_path / "b.txt"
    p.write_text("old")
    p.chmod(0o600)
    write_text_atomic(p, "new")
    assert p.read_text() == "new" and p.stat().st_mode & 0o777 == 0o600
