"""Where session files live, and the list of them the start screen offers to resume.

The sessions directory is, in this order: ``--sessions DIR``, the environment variable
``HEXCAL_SESSIONS``, else the user's data directory (platformdirs): ``~/.local/share/hexcal/
sessions`` on Linux, ``~/Library/Application Support/hexcal/sessions`` on macOS,
``%LOCALAPPDATA%\\hexcal\\sessions`` on Windows. A new session is named by its start time
(``hexcal-session-YYYYmmdd-HHMMSS.json``), so sessions never land in whatever folder the
operator started hexcal from.

Listing reads each file within the limits of :mod:`hexcal.io.safe_read` but does not validate
it: a damaged file is listed with what is wrong (and never touched), so no session is hidden.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

from hexcal.errors import InputError
from hexcal.io.safe_read import read_json

#: Environment variable naming the sessions directory.
ENV = "HEXCAL_SESSIONS"
#: Pattern of the files listed (the temporary files of an atomic write are not).
PATTERN = "*.json"


def sessions_dir(given: str | Path | None = None) -> Path:
    """The sessions directory (see the module docstring); not created here."""
    if given:
        return Path(given).expanduser()
    env = os.environ.get(ENV)
    if env:
        return Path(env).expanduser()
    from platformdirs import user_data_path

    return user_data_path("hexcal") / "sessions"


def new_session_path(directory: Path, now: float | None = None) -> Path:
    """A new session file's path in ``directory``, named by the time (a second apart at least;
    a name already taken gets ``-2``, ``-3``...)."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(now))
    path = directory / f"hexcal-session-{stamp}.json"
    n = 2
    while path.exists():
        path = directory / f"hexcal-session-{stamp}-{n}.json"
        n += 1
    return path


@dataclass(frozen=True)
class SessionEntry:
    """One session file as the start screen lists it. ``problem``: why it cannot be read (the
    other fields are then empty)."""

    path: Path
    modified: float
    robot: str = ""
    created: str = ""
    poses: int = 0
    last_step: str = ""
    problem: str = ""

    #: The table's columns, in the order of :meth:`row`.
    #: "changed" before "robot": at 80 columns the last column is the one cut.
    COLUMNS = ("file", "poses", "last step", "changed", "robot")

    def row(self) -> tuple[str, str, str, str, str]:
        """(file, poses, last step, when changed, robot) for a table."""
        when = datetime.fromtimestamp(self.modified).strftime("%Y-%m-%d %H:%M")
        if self.problem:
            return (self.path.name, "—", f"unreadable: {self.problem}", when, "—")
        return (self.path.name, str(self.poses), self.last_step or "—", when, self.robot)


def _entry(path: Path) -> SessionEntry:
    modified = path.stat().st_mtime
    try:
        data: Any = read_json(path, "session", InputError)
    except InputError as exc:
        return SessionEntry(path, modified, problem=str(exc).removeprefix(f"{path}: "))
    if not isinstance(data, dict) or "schema_version" not in data:
        return SessionEntry(path, modified, problem="not a hexcal session file")
    robot = data.get("robot")
    poses = data.get("poses")
    progress = data.get("progress")
    last = ""
    if isinstance(progress, list) and progress and isinstance(progress[-1], dict):
        last = f"{progress[-1].get('step', '')} ({progress[-1].get('status', '')})"
    elif isinstance(poses, list) and poses and isinstance(poses[-1], dict):
        last = str(poses[-1].get("step", ""))
    return SessionEntry(
        path,
        modified,
        robot=str(robot.get("name", "robot")) if isinstance(robot, dict) else "?",
        created=str(data.get("created", "")),
        poses=(len(poses) if isinstance(poses, list) else 0) + _imported(data.get("pose_block")),
        last_step=last,
    )


def _imported(block: Any) -> int:
    """The poses of a session's pose block (an imported table), as its file says."""
    n = block.get("poses") if isinstance(block, dict) else None
    return n if isinstance(n, int) and not isinstance(n, bool) and n > 0 else 0


def list_sessions(directory: Path, limit: int = 50) -> list[SessionEntry]:
    """The session files in ``directory``, the most recently changed first (at most
    ``limit``); an absent directory has none."""
    if not directory.is_dir():
        return []
    files = sorted(
        (p for p in directory.glob(PATTERN) if p.is_file() and not p.name.startswith(".")),
        key=lambda p: p.stat().st_mtime,
        reverse=True,
    )
    return [_entry(p) for p in files[:limit]]
