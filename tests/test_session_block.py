"""A session's imported table in its pose block: streamed in by ``session import`` (a block of
rows at a time; a table beyond the limit refused before anything is written), read back bit for
bit, refused when damaged (naming the file, never overwritten), and older session files (poses
as JSON) still read."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from hexcal.app.cli import main
from hexcal.estimate.model_file import load_robot
from hexcal.io import capacity
from hexcal.io.measurements_csv import _BLOCK_ROWS, read_measurements
from hexcal.io.pose_block import HEADER_BYTES, PoseBlockWriter
from hexcal.procedure.session import (
    Session,
    SessionFile,
    SessionFileError,
    export_session,
    import_table,
    load_session,
)
from hexcal.procedure.session_merge import merge_sessions

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "left-hand-sim"
ROBOT = EXAMPLE / "robot.json"


def _table(path: Path, poses: int, delimiter: str = ",", extra: bool = True) -> Path:
    """``poses`` rows from the example's (new ids, later times), with an extra text column
    whose cells are all different (``note``) when ``extra``."""
    with open(EXAMPLE / "measurements.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    span = float(rows[-1]["t"]) + 10.0
    fields = [*rows[0], "note"] if extra else list(rows[0])
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fields, delimiter=delimiter)
        w.writeheader()
        for i in range(poses):
            r = dict(rows[i % len(rows)])
            r["pose_id"] = str(i + 1)
            r["t"] = repr(float(r["t"]) + span * (i // len(rows)))
            if extra:
                r["note"] = f"take {i % 7} ö,{i}"
            w.writerow(r)
    return path


def _blocks(folder: Path) -> list[Path]:
    return sorted(folder.glob("*.poses.npy"))


def test_import_round_trips_bit_for_bit_through_the_pose_block(tmp_path):
    src = _table(tmp_path / "m.csv", 500)
    out = tmp_path / "s.json"
    path, n = import_table(src, load_robot(ROBOT), out)
    assert (path, n) == (out, 500)
    [block] = _blocks(tmp_path)
    assert block.name.startswith("s.json.") and block.stat().st_size == HEADER_BYTES + 500 * 141
    doc = json.loads(out.read_text())
    assert doc["schema_version"] == 3 and doc["poses"] == []
    assert doc["pose_block"]["file"] == block.name and doc["pose_block"]["poses"] == 500
    session = load_session(out)
    assert session.measurements() == read_measurements(src)  # every float bit for bit, texts
    # The block is a plain .npy: NumPy reads it without pickle.
    records = np.load(block, allow_pickle=False)
    assert records.shape == (500,) and np.array_equal(records["t"], read_measurements(src).t)
    export_session(session, tmp_path / "x")
    assert read_measurements(tmp_path / "x" / "measurements.csv") == read_measurements(src)


def test_import_streams_the_table_a_block_of_rows_at_a_time(tmp_path, monkeypatch):
    """The writer is handed the rows as they are read, never the whole table, in hexcal's own
    dialect (which a read of the whole table takes in at once, up to 64 MB) as in another
    (semicolons here)."""
    sizes: list[int] = []
    add = PoseBlockWriter.add

    def spy(self, pose_id, *args, **kwargs):
        sizes.append(len(pose_id))
        return add(self, pose_id, *args, **kwargs)

    monkeypatch.setattr(PoseBlockWriter, "add", spy)
    for name, delimiter in (("plain.csv", ","), ("semi.csv", ";")):
        sizes.clear()
        src = _table(tmp_path / name, 3 * _BLOCK_ROWS + 5, delimiter)
        import_table(src, load_robot(ROBOT), tmp_path / f"{name}.json")
        assert sum(sizes) == 3 * _BLOCK_ROWS + 5 and max(sizes) <= _BLOCK_ROWS, sizes
        assert load_session(tmp_path / f"{name}.json").measurements() == read_measurements(src)


def _nothing_may_be_written(monkeypatch) -> None:
    """Make taking the session's lock and opening any file hexcal streams into (the pose
    block's temporary file) fail the test."""
    import hexcal.io.pose_block as pose_block
    import hexcal.procedure.session as session_module

    def written(*args, **kwargs):
        raise AssertionError("something was written before the refusal")

    monkeypatch.setattr(pose_block, "StreamedFile", written)
    monkeypatch.setattr(session_module, "_acquire", written)


def test_a_table_beyond_the_limit_is_refused_before_anything_is_written(tmp_path, monkeypatch):
    """5,000 rows against a limit of 4,100: the rows are counted before the lock is taken or
    the block's temporary file opened (either fails the test here), and the message names
    the count and the limit; the folder stays empty."""
    src = _table(tmp_path / "m.csv", 5000)
    monkeypatch.setattr(capacity, "MAX_IMPORTED_POSES", 4100)
    _nothing_may_be_written(monkeypatch)
    out = tmp_path / "out" / "s.json"
    out.parent.mkdir()
    with pytest.raises(SessionFileError) as err:
        import_table(src, load_robot(ROBOT), out)
    assert str(err.value).startswith(f"{src}: 5,000 poses; a session holds at most 4,100")
    assert "MAX_IMPORTED_POSES" in str(err.value) and f"{out} was not written" in str(err.value)
    assert list(out.parent.iterdir()) == []


def test_blank_lines_and_line_breaks_in_cells_are_not_counted_as_poses(tmp_path, monkeypatch):
    """The line ends only bound the rows: a table at the limit whose blank lines and quoted
    line breaks take its line ends past it is counted exactly, and imported."""
    src = _table(tmp_path / "m.csv", 100)
    lines = src.read_text().splitlines()
    lines[1] = lines[1].replace("take 0 ö,0", "take 0\n\nsecond line")  # a quoted cell
    src.write_text("\n\n".join(lines) + "\n\n\n")
    monkeypatch.setattr(capacity, "MAX_IMPORTED_POSES", 100)
    out = tmp_path / "s.json"
    assert import_table(src, load_robot(ROBOT), out) == (out, 100)
    assert load_session(out).measurements().extra["note"][0] == "take 0\n\nsecond line"
    monkeypatch.setattr(capacity, "MAX_IMPORTED_POSES", 99)
    _nothing_may_be_written(monkeypatch)
    with pytest.raises(SessionFileError, match="100 poses; a session holds at most 99"):
        import_table(src, load_robot(ROBOT), tmp_path / "t.json")


def test_a_table_within_the_bound_is_not_parsed_twice(tmp_path, monkeypatch):
    import hexcal.procedure.session_block as session_block

    def parsed(path):
        raise AssertionError("counted by parsing although its line ends are within the limit")

    monkeypatch.setattr(session_block, "count_rows", parsed)
    monkeypatch.setattr(capacity, "MAX_IMPORTED_POSES", 101)  # 100 rows and the header's end
    out = tmp_path / "s.json"
    assert import_table(_table(tmp_path / "m.csv", 100), load_robot(ROBOT), out) == (out, 100)


def test_a_table_that_grew_after_it_was_counted_is_refused_as_it_streams(tmp_path, monkeypatch):
    """The writer holds the limit too (here the count before the import is made to miss
    the rows: 5,000 rows against a limit of 4,100, so the second block of rows passes it): no
    session file, no block, no temporary file and no lock remain; the message names the
    limit."""
    import hexcal.procedure.session_block as session_block

    src = _table(tmp_path / "m.csv", 5000)
    monkeypatch.setattr(capacity, "MAX_IMPORTED_POSES", 4100)
    monkeypatch.setattr(session_block, "line_ends", lambda path: 0)
    out = tmp_path / "out" / "s.json"
    out.parent.mkdir()
    with pytest.raises(SessionFileError) as err:
        import_table(src, load_robot(ROBOT), out)
    assert "more than 4,100 poses; a session holds at most 4,100" in str(err.value)
    assert "MAX_IMPORTED_POSES" in str(err.value) and f"{out} was not written" in str(err.value)
    assert list(out.parent.iterdir()) == []


def test_the_reader_refuses_a_block_beyond_the_limit_the_writer_keeps(tmp_path, monkeypatch):
    """One limit for both: a block written under it is refused by a reader held to a lower one
    (the same constant), naming it."""
    import_table(_table(tmp_path / "m.csv", 300), load_robot(ROBOT), tmp_path / "s.json")
    monkeypatch.setattr(capacity, "MAX_IMPORTED_POSES", 299)
    with pytest.raises(SessionFileError, match=r"300 poses; a session holds at most 299"):
        load_session(tmp_path / "s.json")


@pytest.mark.parametrize(
    ("damage", "said"),
    [
        (lambda b: b[: len(b) - 141], "cut short"),
        (lambda b: b + b"\0", "longer than its poses"),
        (lambda b: b[:-7] + bytes([b[-7] ^ 1]) + b[-6:], "do not match the checksum"),
        (lambda b: b"not numpy" + b[9:], "not a pose block"),
        (lambda b: b.replace(b"'<f8'", b"'<f4'", 1), "not the pose record"),
        (lambda b: b[:8] + b"\x00\x01" + b[10:], "does not give its length as 1014 bytes"),
    ],
    ids=["truncated", "longer", "flipped-bit", "not-npy", "other-layout", "header-length"],
)
def test_a_damaged_block_is_refused_naming_it_and_left_untouched(tmp_path, damage, said):
    out = tmp_path / "s.json"
    import_table(_table(tmp_path / "m.csv", 50), load_robot(ROBOT), out)
    [block] = _blocks(tmp_path)
    block.write_bytes(damage(block.read_bytes()))
    damaged, text = block.read_bytes(), out.read_text()
    with pytest.raises(SessionFileError) as err:
        load_session(out)
    assert str(err.value).startswith(f"{block}: ") and said in str(err.value)
    assert "left untouched" in str(err.value)
    with pytest.raises(SessionFileError):
        SessionFile.resume(out)  # the writer refuses it too: nothing is overwritten
    assert block.read_bytes() == damaged and out.read_text() == text


def test_a_missing_block_is_named(tmp_path):
    out = tmp_path / "s.json"
    import_table(_table(tmp_path / "m.csv", 20), load_robot(ROBOT), out)
    [block] = _blocks(tmp_path)
    block.unlink()
    with pytest.raises(SessionFileError, match=rf"{block}: missing; .* together with its"):
        load_session(out)


def test_an_older_session_file_with_its_poses_as_json_is_still_read(tmp_path):
    """Schema 2 (hexcal before the pose block) kept every pose in the JSON: read as before,
    and saved again as schema 3 with its poses where they were."""
    meas = read_measurements(EXAMPLE / "measurements.csv")
    doc = json.loads(Session.from_measurements(meas, load_robot(ROBOT)).model_dump_json())
    doc["schema_version"] = 2
    del doc["pose_block"]
    old = tmp_path / "old.json"
    old.write_text(json.dumps(doc, indent=1))
    assert load_session(old).measurements() == meas
    with SessionFile.resume(old) as sf:
        sf.add_note("read again")
    again = json.loads(old.read_text())
    assert again["schema_version"] == 3 and len(again["poses"]) == 184
    assert _blocks(tmp_path) == []
    assert load_session(old).measurements() == meas


def test_saving_again_keeps_the_block_and_recorded_poses_follow_the_table(tmp_path):
    from test_session import recorded_pose

    from hexcal.vocabulary import Constraint

    out = tmp_path / "s.json"
    src = _table(tmp_path / "m.csv", 40, extra=False)
    import_table(src, load_robot(ROBOT), out)
    [block] = _blocks(tmp_path)
    before = block.read_bytes()
    with SessionFile.resume(out) as sf:
        pose = recorded_pose(np.random.default_rng(1))
        record = sf.session.pose_record(pose, "extra", 0, Constraint.FREE, 1e4, 20.5)
        assert record.pose_id == 41  # after the table's ids
        sf.add_pose(record)
    assert _blocks(tmp_path) == [block] and block.read_bytes() == before
    m = load_session(out).measurements()
    assert len(m) == 41 and m.pose_id[-1] == 41 and m.temperature[-1] == 20.5
    assert m.subset(slice(0, 40)) == read_measurements(src)


def test_an_in_memory_table_is_written_as_a_block_on_first_save(tmp_path):
    meas = read_measurements(EXAMPLE / "measurements.csv")
    SessionFile.create(tmp_path / "s.json", Session.with_table(meas, load_robot(ROBOT))).close()
    assert len(_blocks(tmp_path)) == 1
    assert load_session(tmp_path / "s.json").measurements() == meas


def test_merge_keeps_one_table_and_refuses_two_different_ones(tmp_path):
    robot = load_robot(ROBOT)
    import_table(_table(tmp_path / "a.csv", 30), robot, tmp_path / "a.json")
    import_table(_table(tmp_path / "a.csv", 30), robot, tmp_path / "b.json")
    import_table(_table(tmp_path / "c.csv", 31), robot, tmp_path / "c.json")
    merged, _ = merge_sessions(load_session(tmp_path / "a.json"), load_session(tmp_path / "b.json"))
    (tmp_path / "sub").mkdir()
    SessionFile.create(tmp_path / "sub" / "m.json", merged).close()
    assert len(_blocks(tmp_path / "sub")) == 1  # written beside the new file
    assert load_session(tmp_path / "sub" / "m.json").measurements() == read_measurements(
        tmp_path / "a.csv"
    )
    with pytest.raises(SessionFileError, match="different imported tables"):
        merge_sessions(load_session(tmp_path / "a.json"), load_session(tmp_path / "c.json"))


def test_the_command_streams_and_every_reader_reads_the_session(tmp_path, capsys):
    src = _table(tmp_path / "m.csv", 300)
    out = tmp_path / "s.json"
    assert main(["session", "import", str(src), "--robot", str(ROBOT), "--out", str(out)]) == 0
    assert f"session {out} created with 300 poses" in capsys.readouterr().out
    from hexcal.app.workflow import read_inputs

    assert read_inputs(out).meas == read_measurements(src)


def test_a_repeated_pose_id_is_refused_by_line_and_nothing_is_written(tmp_path):
    """The streamed import checks the ids of the rows it has written: a repeat found at the end
    names both lines, and the block written so far is removed."""
    src = _table(tmp_path / "m.csv", 2 * _BLOCK_ROWS, ";")
    text = src.read_text().splitlines()
    text[-1] = "7;" + text[-1].split(";", 1)[1]  # the last row takes row 7's id (line 8)
    src.write_text("\n".join(text) + "\n")
    out = tmp_path / "out" / "s.json"
    out.parent.mkdir()
    with pytest.raises(ValueError, match=rf"line {2 * _BLOCK_ROWS + 1}.*already used on line 8"):
        import_table(src, load_robot(ROBOT), out)
    assert list(out.parent.iterdir()) == []


def test_a_block_no_session_names_is_removed_when_its_name_is_used_again(tmp_path, caplog):
    """A session file deleted and another table imported under its name: its old block goes
    (said), unless another file beside it names it (a session saved from it under another
    name); blocks of other names, and files not named as blocks are, are left alone."""
    robot = load_robot(ROBOT)
    out = tmp_path / "s.json"
    import_table(_table(tmp_path / "a.csv", 30), robot, out)
    [first] = _blocks(tmp_path)
    keep = [tmp_path / "s.json.notes.poses.npy", tmp_path / "t.json.0123456789ab.poses.npy"]
    for p in keep:
        p.write_bytes(b"not mine")
    out.unlink()
    import_table(_table(tmp_path / "b.csv", 31), robot, out)
    assert not first.exists() and f"{first}: removed, a pose block of s.json" in caplog.text
    assert all(p.read_bytes() == b"not mine" for p in keep)
    [second] = [b for b in _blocks(tmp_path) if b not in keep]
    assert len(load_session(out).measurements()) == 31

    # The same again, while a copy saved beside it under another name still names the block.
    copy = tmp_path / "copy.json"
    copy.write_text(out.read_text())
    out.unlink()
    import_table(_table(tmp_path / "a.csv", 30), robot, out)
    assert second.exists() and len(load_session(copy).measurements()) == 31
    # Resuming tidies too (a save interrupted between its block and its file leaves one).
    orphan = tmp_path / "s.json.abcdefabcdef.poses.npy"
    orphan.write_bytes(b"an interrupted save's block")
    with SessionFile.resume(out) as sf:
        assert any(n.startswith(f"{orphan}: removed") for n in sf.notices)
    assert not orphan.exists() and second.exists() and len(load_session(out).measurements()) == 30
