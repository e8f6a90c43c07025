"""Atomic writes, by behaviour: a writer killed at random instants leaves the old or the new
file whole, and a reader beside a writer sees only whole files (no test patches the writer); a
new file gets the umask's mode, an existing file keeps its own; the temporary files of an
interrupted write are found by their naming."""

from __future__ import annotations

import errno
import os
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from hexcal.io.fileio import (
    OutputFileError,
    check_output,
    orphan_temp_files,
    remove_orphan_temp_files,
    write_error,
    write_files_atomic,
    write_text_atomic,
)


def test_new_file_mode_follows_umask(tmp_path):
    old = os.umask(0o022)
    try:
        write_text_atomic(tmp_path / "a.txt", "x")
    finally:
        os.umask(old)
    assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o644
    assert [p.name for p in tmp_path.iterdir()] == ["a.txt"]


@pytest.mark.parametrize("mode", [0o600, 0o755, 0o641])
def test_existing_mode_kept(tmp_path, mode):
    p = tmp_path / "b.txt"
    p.write_text("old")
    p.chmod(mode)
    write_text_atomic(p, "new")
    assert p.read_text() == "new" and p.stat().st_mode & 0o777 == mode


@pytest.mark.parametrize(
    ("code", "words"),
    [
        (errno.ENOENT, "the folder {folder} does not exist; create it"),
        (errno.EISDIR, "is a folder; give a file name inside it"),
        (errno.ENOTDIR, "{folder} is not a folder; choose another path"),
        (errno.EACCES, "no permission to write in {folder}"),
        (errno.EPERM, "no permission to write in {folder}"),
        (errno.EROFS, "{folder} is on a read-only file system"),
        (errno.ENOSPC, "the disk is full; free some space"),
        (errno.EDQUOT, "the disk quota is exceeded"),
        (errno.EIO, "cannot be written ({why}); check the path and its folder"),
    ],
)
def test_each_os_error_is_said_in_the_users_terms(tmp_path, code, words):
    """The error names the user's path and what to do, one sentence per cause."""
    path = tmp_path / "missing" / "out.json" if code == errno.ENOENT else tmp_path / "out.json"
    error = write_error(OSError(code, os.strerror(code)), path)
    message = str(error)
    assert error.path == path and message.startswith(f"{path}: ")
    assert words.format(folder=path.parent, why=os.strerror(code)) in message
    others = [w for c, w in WORDS.items() if c != code and w not in words]
    assert not any(w in message for w in others), message


WORDS = {
    errno.ENOENT: "does not exist",
    errno.EISDIR: "is a folder;",
    errno.ENOSPC: "the disk is full",
    errno.EDQUOT: "quota",
    errno.EROFS: "read-only",
}


def test_only_a_missing_file_or_folder_is_said_to_be_missing(tmp_path):
    """The folder's absence qualifies ENOENT alone: a permission error in a folder that is gone
    meanwhile is still said as a permission error."""
    path = tmp_path / "gone" / "out.json"
    message = str(write_error(OSError(errno.EACCES, "Permission denied"), path))
    assert "no permission to write in" in message and "does not exist" not in message


def test_check_output_takes_a_file_to_replace_and_a_folder_to_make(tmp_path):
    """A file that exists may be replaced (the caller's rule, not check_output's); an output
    folder that does not exist yet is made later, in a parent that does."""
    existing = tmp_path / "out.json"
    existing.write_text("{}")
    check_output(existing)
    check_output(tmp_path / "new-folder", folder=True)
    with pytest.raises(OutputFileError, match="is a file, but a folder is wanted"):
        check_output(existing, folder=True)


def test_a_failed_write_of_several_files_leaves_no_file_and_no_folder_it_made(tmp_path):
    """A text that cannot be encoded (a lone surrogate) fails the second file before any
    rename: neither file is there, nor the two folders the call made; the folder that was
    there stays."""
    (tmp_path / "kept.txt").write_text("x")
    folder = tmp_path / "new" / "deeper"
    with pytest.raises(UnicodeEncodeError):
        write_files_atomic(folder, {"a.txt": "fine", "b.txt": "bad \ud800"})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept.txt"]
    write_files_atomic(folder, {"a.txt": "fine", "b.txt": "also"})
    assert (folder / "a.txt").read_text() == "fine" and (folder / "b.txt").read_text() == "also"
    assert sorted(p.name for p in folder.iterdir()) == ["a.txt", "b.txt"]
    write_files_atomic(folder, {"a.txt": "again"})  # into a folder that exists
    assert (folder / "a.txt").read_text() == "again"


@pytest.mark.skipif(os.geteuid() == 0, reason="root may delete in any folder")
def test_an_orphan_that_cannot_be_removed_is_left(tmp_path):
    """In a folder this process may not write in, the orphan stays and nothing is raised."""
    folder = tmp_path / "ro"
    folder.mkdir()
    (folder / "out.txt").write_text("x")
    (folder / ".out.txt.abcdefgh.tmp").write_text("half")
    folder.chmod(0o500)
    try:
        assert remove_orphan_temp_files(folder / "out.txt") == []
        assert (folder / ".out.txt.abcdefgh.tmp").read_text() == "half"
    finally:
        folder.chmod(0o700)


def test_a_write_that_fails_on_the_text_leaves_the_old_file_and_no_temporary_one(tmp_path):
    path = tmp_path / "out.txt"
    path.write_text("old")
    with pytest.raises(UnicodeEncodeError):
        write_text_atomic(path, "bad \ud800")
    assert path.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["out.txt"]


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write in any folder")
def test_a_folder_without_write_permission_is_refused(tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        with pytest.raises(OutputFileError, match="no permission to write in"):
            check_output(folder / "out.json")
    finally:
        folder.chmod(0o700)


# -- behaviour: a killed writer, a reader beside a writer ----------------------------------------
#: Two contents told apart at a glance, large enough (MB) that writing one takes a while: a write
#: in place would be caught half done (truncated, or empty between the truncation and the data).
A, B = "A" * 3_000_000 + "\n", "B" * 2_000_000 + "\n"
WRITER = textwrap.dedent(
    """
    import sys
    from hexcal.io.fileio import write_text_atomic
    path, a, b = sys.argv[1], "A" * 3_000_000 + "\\n", "B" * 2_000_000 + "\\n"
    write_text_atomic(path, a)
    print("ready", flush=True)
    while True:
        write_text_atomic(path, b)
        write_text_atomic(path, a)
    """
)


def _writer(path: Path) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE)
    assert proc.stdout is not None and proc.stdout.readline().strip() == b"ready"
    return proc


def test_a_writer_killed_at_random_instants_leaves_the_old_or_the_new_file_whole(tmp_path):
    """SIGKILL a process rewriting one file (3 MB and 2 MB contents in turn) at 12 random
    instants: the file is always one of the two, complete — never truncated or empty, which a
    write in place leaves whenever the kill lands in it. A kill inside a write leaves its one
    temporary file, which orphan_temp_files finds by its naming (and no other file's)."""
    rng = random.Random(40)
    path = tmp_path / "out.txt"
    (tmp_path / ".other.txt.abcdefgh.tmp").write_text("another file's")  # not out.txt's
    seen, cut = set(), 0
    for _ in range(12):
        proc = _writer(path)
        time.sleep(rng.uniform(0.0, 0.15))
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        text = path.read_text()
        assert text in (A, B), f"a {len(text)}-character file, starting {text[:10]!r}"
        seen.add(text[0])
        orphans = orphan_temp_files(path)  # at most the one write the kill cut short
        assert len(orphans) <= 1 and all(o.name.startswith(".out.txt.") for o in orphans)
        sizes = [(o, o.stat().st_size) for o in orphans]
        assert remove_orphan_temp_files(path) == sizes
        cut += len(orphans)
    assert seen == {"A", "B"}  # the kills landed while both were being written
    assert cut  # and some in a write: its temporary file is found by its naming, and removed
    assert sorted(p.name for p in tmp_path.iterdir()) == [".other.txt.abcdefgh.tmp", "out.txt"]


def test_a_reader_beside_a_writer_sees_only_whole_files(tmp_path):
    """A process rewrites one file (3 MB and 2 MB contents in turn) while this one reads it 300
    times: every read is one of the two, complete, and both are seen."""
    path = tmp_path / "out.txt"
    proc = _writer(path)
    try:
        seen = []
        for _ in range(300):
            text = path.read_text()
            assert text in (A, B), f"read a {len(text)}-character file, starting {text[:10]!r}"
            seen.append(text[0])
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    assert set(seen) == {"A", "B"}


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


def test_a_streamed_file_is_renamed_whole_or_leaves_nothing(tmp_path):
    from hexcal.io.fileio import StreamedFile, orphan_temp_files

    owner = tmp_path / "s.json"
    f = StreamedFile(owner)
    f.fh.write(b"part one, ")
    assert orphan_temp_files(owner) == [f.tmp]  # an interrupted write is the owner's orphan
    f.fh.write(b"part two")
    f.publish(tmp_path / "s.json.abc.poses.npy")
    assert (tmp_path / "s.json.abc.poses.npy").read_bytes() == b"part one, part two"
    g = StreamedFile(owner)
    g.fh.write(b"never kept")
    err = g.error(OSError(28, "No space left on device"))
    assert str(owner) in str(err) and list(tmp_path.iterdir()) == [
        tmp_path / "s.json.abc.poses.npy"
    ]
