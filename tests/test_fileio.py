"""Atomic writes: no temporary file left behind, a new file gets the umask's mode, an existing
file keeps its own; the temporary files of an interrupted write are found by their naming."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from hexcal.io.fileio import orphan_temp_files, remove_orphan_temp_files, write_text_atomic


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


def test_a_killed_write_leaves_a_temp_file_that_orphan_temp_files_finds(tmp_path, monkeypatch):
    """The naming the cleanup matches is the naming write_text_atomic uses: simulate a kill
    between the write and the rename (the temporary file is neither renamed nor removed)."""
    target = tmp_path / "session.json"
    target.write_text("old")

    def killed(*args):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", killed)
    monkeypatch.setattr(Path, "unlink", lambda self, missing_ok=False: None)
    with pytest.raises(KeyboardInterrupt):
        write_text_atomic(target, "new" * 1000)
    monkeypatch.undo()
    (tmp_path / "other.json").write_text("x")
    (tmp_path / ".other.json.abcdefgh.tmp").write_text("another file's")
    orphans = orphan_temp_files(target)
    assert len(orphans) == 1 and orphans[0].name.startswith(".session.json.")
    assert remove_orphan_temp_files(target) == [(orphans[0], 3000)]
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        ".other.json.abcdefgh.tmp",
        "other.json",
        "session.json",
    ]
    assert target.read_text() == "old"
