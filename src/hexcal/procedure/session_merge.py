"""Two versions of one session merged: what a save that met another program's change kept apart
(:class:`~hexcal.procedure.session.SessionConflict`) brought together again.

``theirs`` (the file on disk) is the base; whatever ``mine`` holds that ``theirs`` does not is
added: poses (a pose is the same pose when its step, time, pose and readings are), set-aside
poses, notes, finished steps and results. A pose of ``mine`` whose id ``theirs`` already uses
for another pose gets the next free id, and the results of ``mine`` follow it. Poses stay in the
order recorded (by ``recorded_at`` where every pose has one), since backlash depends on it.
Nothing is dropped: a merge only adds.
"""

from __future__ import annotations

from typing import Any

from hexcal.procedure.session_model import PoseRecord, Session, SessionFileError


def _pose_key(p: PoseRecord) -> tuple[Any, ...]:
    return (p.step, p.t, tuple(p.position), tuple(p.quaternion), tuple(p.readings), p.recorded_at)


def _added(base: list[Any], more: list[Any], key: Any) -> list[Any]:
    have = {key(x) for x in base}
    return [x for x in more if key(x) not in have]


def merge_sessions(theirs: Session, mine: Session) -> tuple[Session, list[str]]:
    """``theirs`` with everything ``mine`` adds (see the module docstring), and what was added,
    in words. Refused (:class:`SessionFileError`) when the two are not versions of one session
    (another robot or procedure)."""
    if theirs.robot != mine.robot or theirs.procedure != mine.procedure:
        raise SessionFileError(
            "the two files are not versions of one session (their robot or procedure differ); "
            "they are not merged"
        )
    a, b = theirs.pose_block, mine.pose_block
    if (a is None) != (b is None) or (a is not None and b is not None and a.sha256 != b.sha256):
        raise SessionFileError(
            "the two files hold different imported tables (their pose blocks differ), so they "
            "are not versions of one session; they are not merged"
        )
    merged = theirs.model_copy(deep=True)
    said: list[str] = []
    for c in mine.columns:  # a column mine's poses brought (a temperature, an extra cell)
        if c not in merged.columns:
            merged.columns.append(c)
    used = {p.pose_id for p in merged.poses}
    used |= {s.pose.pose_id for s in merged.set_aside if s.pose is not None}
    next_id = max(merged.next_pose_id(), max(used, default=0) + 1)
    renumbered: dict[int, int] = {}
    new_poses = []
    for p in _added(merged.poses, mine.poses, _pose_key):
        if p.pose_id in used:
            renumbered[p.pose_id] = next_id
            p = p.model_copy(update={"pose_id": next_id})
            next_id += 1
        used.add(p.pose_id)
        new_poses.append(p)
    if new_poses:
        poses = merged.poses + new_poses
        if all(p.recorded_at is not None for p in poses):
            poses.sort(key=lambda p: p.recorded_at)
        merged.poses = poses
        moved = "".join(f", {a}→{b}" for a, b in renumbered.items())
        said.append(f"{len(new_poses)} pose(s)" + (f" (renumbered{moved[1:]})" if moved else ""))
    aside = _added(merged.set_aside, mine.set_aside, lambda s: (s.step, s.reason, s.at))
    merged.set_aside += aside
    notes = _added(merged.notes, mine.notes, lambda n: (n.at, n.text))
    merged.notes = sorted(merged.notes + notes, key=lambda n: n.at)
    progress = _added(merged.progress, mine.progress, lambda s: (s.step, s.status, s.at))
    merged.progress = sorted(merged.progress + progress, key=lambda s: s.at)
    results = []
    for r in _added(merged.results, mine.results, lambda r: (r.kind, r.at)):
        ids = [renumbered.get(i, i) for i in r.pose_ids]
        results.append(r.model_copy(update={"pose_ids": ids}))
    merged.results = sorted(merged.results + results, key=lambda r: r.at)
    if merged.instruments is None and mine.instruments is not None:
        merged.instruments = mine.instruments
        said.append("the noise")
    for n, what in ((len(aside), "set-aside pose(s)"), (len(notes), "note(s)")):
        if n:
            said.append(f"{n} {what}")
    for n, what in ((len(progress), "finished step(s)"), (len(results), "result(s)")):
        if n:
            said.append(f"{n} {what}")
    return merged, said
