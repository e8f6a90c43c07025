"""Fuzzing the session file's writers (hypothesis; marked ``fuzz``: CI's long pass runs it with
``HEXCAL_FUZZ=1``): two processes started together on a barrier, each resuming one session and
making a drawn sequence of changes (notes, poses, undoing the last pose), one of them perhaps
killed mid-way, one perhaps only looking (read-only). Whatever the interleaving: the file
always loads; every change of a writer that exited 0 is in it, in its order; a killed writer's
changes up to its last completed save are in it; a writer refused at the door exits non-zero,
told which process holds the session; a crashed holder's lock is taken over by the next
opener, who is told."""

from __future__ import annotations

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
