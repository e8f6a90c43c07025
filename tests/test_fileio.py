"""Atomic writes: no temporary file left behind, a new file gets the umask's mode, an existing
file keeps its own; the temporary files of an interrupted write are found by their naming."""

from __future__ import annotations

import errno
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


def _failing(code: int):
    """A writer that writes a little, then fails as the disk or the file-size limit would."""

    def write(path: Path) -> None:
        path.write_bytes(b"\x89PNG partial")
        raise OSError(code, os.strerror(code))

    return write


@pytest.mark.parametrize(
    ("code", "said"),
    [(errno.ENOSPC, "the disk is full"), (errno.EFBIG, "file-size limit, ulimit -f")],
)
def test_a_figure_that_fails_leaves_nothing_and_names_the_users_path(tmp_path, code, said):
    from hexcal.io.fileio import OutputFileError, write_atomic_with

    target = tmp_path / "pose_error.png"
    with pytest.raises(OutputFileError) as exc:
        write_atomic_with(target, _failing(code))
    assert str(exc.value).startswith(f"{target}: ") and said in str(exc.value)
    assert list(tmp_path.iterdir()) == []
    write_atomic_with(target, lambda p: p.write_bytes(b"whole"))
    assert target.read_bytes() == b"whole" and [p.name for p in tmp_path.iterdir()] == [
        "pose_error.png"
    ]


def test_a_new_folder_is_removed_when_what_fills_it_fails(tmp_path):
    from hexcal.io.fileio import new_folder

    with pytest.raises(RuntimeError), new_folder(tmp_path / "a" / "b") as out:
        assert out.is_dir()
        raise RuntimeError
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "kept").mkdir()
    with pytest.raises(RuntimeError), new_folder(tmp_path / "kept" / "new"):
        raise RuntimeError
    assert [p.name for p in tmp_path.iterdir()] == ["kept"]
    assert list((tmp_path / "kept").iterdir()) == []


def test_several_files_in_subfolders_are_all_or_nothing(tmp_path, monkeypatch):
    from hexcal.io.fileio import OutputFileError, write_files_atomic

    files = {"README.md": "r", "a/b/c.txt": "c", "a/d.txt": "d"}
    write_files_atomic(tmp_path / "ex", files)
    assert (tmp_path / "ex" / "a" / "b" / "c.txt").read_text() == "c"
    real = os.fdopen
    calls = []

    def full(fd, *args, **kw):  # the third file meets a full disk
        calls.append(fd)
        if len(calls) == 3:
            os.close(fd)
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(fd, *args, **kw)

    monkeypatch.setattr(os, "fdopen", full)
    with pytest.raises(OutputFileError, match=r"new/a/d.txt: the disk is full"):
        write_files_atomic(tmp_path / "new", files)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ex"]
