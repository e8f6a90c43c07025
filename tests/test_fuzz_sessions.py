"""Fuzzing the session file's writers (hypothesis; marked ``fuzz``: CI's long pass runs it with
``HEXCAL_FUZZ=1``): two processes started together on a barrier, each resuming one session and
making a drawn sequence of changes (notes, poses, undoing the last pose), one of them perhaps
killed mid-way, one perhaps only looking (read-only). Whatever the interleaving: the file
always loads; every change of a writer that exited 0 is in it, in its order; a killed writer's
changes up to its last completed save are in it; a writer refused at the door exits non-zero,
told which process holds the session; a crashed holder's lock is taken over by the next
opener, who is told."""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import signal
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hexcal.acquire.acquisition import RecordedPose
from hexcal.estimate.model_file import load_robot
from hexcal.io.measurements_csv import read_measurements
from hexcal.procedure.session import Session, SessionFile, load_session
from hexcal.procedure.session_lock import SessionLocked

pytestmark = [
    pytest.mark.fuzz,
    pytest.mark.skipif(sys.platform == "win32", reason="fork start method"),
]
EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "left-hand-sim"
FORK = mp.get_context("fork") if sys.platform != "win32" else None
#: Examples: a few in the quick run (each forks two processes), many in the long pass.
EXAMPLES = 1000 if os.environ.get("HEXCAL_FUZZ") else 25

OPS = st.lists(st.sampled_from(["note", "pose", "undo"]), min_size=1, max_size=12)
WRITER = st.fixed_dictionaries(
    {
        "ops": OPS,
        "read_only": st.sampled_from([False, False, False, True]),
        "crash_after": st.none() | st.integers(0, 12),
        "delay_ms": st.integers(0, 20),
    }
)


def _pose(tag: str, i: int) -> RecordedPose:
    rng = np.random.default_rng(abs(hash((tag, i))) % 2**32)
    q = np.array([1.0, 0.0, 0.0, 0.0])
    return RecordedPose(1.0, rng.normal(0, 5, 3) + [0, 0, 200], q, rng.normal(70, 5, 6), [], [])


def _writer(path: str, tag: str, plan: dict, barrier, progress: str) -> None:
    """One program's session: exit 0 having made every change, 2 when refused (its message in
    ``progress``), or killed by itself after ``crash_after`` changes."""
    import time

    barrier.wait()
    time.sleep(plan["delay_ms"] / 1000)
    done = Path(progress)
    try:
        sf = SessionFile.resume(path, read_only=plan["read_only"])
    except SessionLocked as exc:
        done.write_text(f"refused {exc}")
        os._exit(2)
    if plan["read_only"]:
        done.write_text("looked")
        os._exit(0)
    for i, op in enumerate(plan["ops"]):
        if plan["crash_after"] == i:
            os.kill(os.getpid(), signal.SIGKILL)
        if op == "note":
            sf.add_note(f"{tag} {i}")
        elif op == "pose":
            sf.add_pose(sf.session.pose_record(_pose(tag, i), "free", 0, "free", t=float(i)))
        else:
            sf.undo_last_pose(f"{tag} {i} undo")
        done.write_text(f"saved {i + 1}")
    sf.close()
    os._exit(0)


def _expected_notes(tag: str, ops: list[str], n: int) -> list[str]:
    return [f"{tag} {i}" for i, op in enumerate(ops[:n]) if op == "note"]


@pytest.fixture(scope="module")
def base_session(tmp_path_factory) -> bytes:
    meas = read_measurements(EXAMPLE / "measurements.csv").subset(slice(0, 4))
    path = tmp_path_factory.mktemp("base") / "s.json"
    session = Session.from_measurements(meas, load_robot(EXAMPLE / "robot.json"))
    with SessionFile.create(path, session):
        pass
    return path.read_bytes()


@settings(
    max_examples=EXAMPLES,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(a=WRITER, b=WRITER)
def test_two_writers_never_lose_a_saved_change(tmp_path_factory, base_session, a, b):
    assert FORK is not None
    folder = tmp_path_factory.mktemp("writers")
    path = folder / "s.json"
    path.write_bytes(base_session)
    barrier = FORK.Barrier(2)
    plans = {"A": a, "B": b}
    procs = {
        tag: FORK.Process(
            target=_writer,
            args=(str(path), tag, plan, barrier, str(folder / f"{tag}.progress")),
            daemon=True,
        )
        for tag, plan in plans.items()
    }
    for p in procs.values():
        p.start()
    for p in procs.values():
        p.join(60)
    session = load_session(path)  # whatever happened, the file loads
    notes = [n.text for n in session.notes]
    for tag, plan in plans.items():
        code = procs[tag].exitcode
        said = (
            (folder / f"{tag}.progress").read_text()
            if (folder / f"{tag}.progress").exists()
            else ""
        )
        mine = [n for n in notes if n.startswith(f"{tag} ")]
        if code == 2:
            other = procs["B" if tag == "A" else "A"].pid
            assert said.startswith("refused") and f"process {other} " in said, said
            assert mine == []
        elif code == 0:
            n = 0 if plan["read_only"] else len(plan["ops"])
            assert mine == _expected_notes(tag, plan["ops"], n)
        else:
            assert code == -signal.SIGKILL and plan["crash_after"] is not None
            # Every save completed before the kill is there (the kill may fall after a save
            # and before its progress line: one change more, never one fewer).
            saved = int(said.split()[1]) if said.startswith("saved") else 0
            assert mine in (
                _expected_notes(tag, plan["ops"], saved),
                _expected_notes(tag, plan["ops"], saved + 1),
            ), (mine, said)
    ids = [p.pose_id for p in session.poses]
    assert len(ids) == len(set(ids))
    with SessionFile.resume(path) as after:  # free again, a crashed holder's lock taken over
        taken = [t for t in after.notices if "took over the lock" in t]
        killed = [t for t, p in procs.items() if p.exitcode == -signal.SIGKILL]
        if not killed:
            assert taken == []
        if taken:
            assert any(f"process {procs[t].pid} " in taken[0] for t in killed)


@pytest.fixture(scope="module")
def imported_session(tmp_path_factory) -> tuple[bytes, bytes]:
    """An imported session's file and its pose block (20 poses: 1,024 + 20 × 141 bytes)."""
    meas = read_measurements(EXAMPLE / "measurements.csv").subset(slice(0, 20))
    path = tmp_path_factory.mktemp("imported") / "s.json"
    SessionFile.create(path, Session.with_table(meas, load_robot(EXAMPLE / "robot.json"))).close()
    [block] = path.parent.glob("*.poses.npy")
    return path.read_bytes(), block.read_bytes()


#: A damage to a pose block: cut to a length, a bit flipped in its records, bytes appended.
DAMAGE = st.one_of(
    st.tuples(st.just("cut"), st.floats(0, 1, exclude_max=True)),
    st.tuples(st.just("flip"), st.floats(0, 1, exclude_max=True), st.integers(0, 7)),
    st.tuples(st.just("append"), st.binary(min_size=1, max_size=300)),
)


@settings(
    max_examples=EXAMPLES * 4,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(damage=DAMAGE)
def test_a_damaged_pose_block_is_refused_naming_it_and_left_as_it_is(
    tmp_path_factory, imported_session, damage
):
    """However a block is cut, flipped (in the records, which the session file's checksum
    covers) or lengthened, loading and resuming the session refuse it naming the block, and
    neither the block nor the session file is changed."""
    from hexcal.io.pose_block import HEADER_BYTES
    from hexcal.procedure.session import SessionFileError

    text, data = imported_session
    folder = tmp_path_factory.mktemp("damaged")
    path = folder / "s.json"
    path.write_bytes(text)
    block = folder / json.loads(text)["pose_block"]["file"]
    if damage[0] == "cut":
        data = data[: int(damage[1] * len(data))]
    elif damage[0] == "flip":
        at = HEADER_BYTES + int(damage[1] * (len(data) - HEADER_BYTES))
        data = data[:at] + bytes([data[at] ^ (1 << damage[2])]) + data[at + 1 :]
    else:
        data = data + damage[1]
    block.write_bytes(data)
    for opening in (load_session, SessionFile.resume):
        with pytest.raises(SessionFileError) as err:
            opening(path)
        assert str(err.value).startswith(f"{block}: "), err.value
    assert block.read_bytes() == data and path.read_bytes() == text
    assert sorted(p.name for p in folder.iterdir()) == sorted([path.name, block.name])
