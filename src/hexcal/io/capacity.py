"""How much a session holds, in one place: the session file's largest size, the recorded poses
that fit in it, and the bounds of a procedure that fills it.

The session's readers (:data:`hexcal.io.safe_read.KINDS`), the procedure loader
(:mod:`hexcal.procedure.steps`) and the command line's pose counts all read these figures, so
a procedure is never accepted that would record a session the readers then refuse. Plain
constants, no imports: the command line reads them while it builds its parser, before any
heavy module is loaded.
"""

from __future__ import annotations

KB = 1024
MB = 1024 * KB

#: The largest session file read (and so written), bytes.
MAX_SESSION_BYTES = 512 * MB
#: A recorded pose's bytes in the session file with its still window's raw samples at the
#: default window (0.25 s of tracker frames and encoder reading sets): a demo session of 71
#: poses took 892,713 bytes, 12.6 KB a pose; rounded up.
RECORDED_POSE_BYTES = 13 * KB
#: The most poses a procedure may ask for in all, counted over its steps and the legs each
#: repeats for: what a session file holds recorded (40,329 poses; at the mock rig's 3 poses a
#: second, under four hours of recording).
MAX_PROCEDURE_POSES = MAX_SESSION_BYTES // RECORDED_POSE_BYTES
#: The most poses an imported table may bring, and a session's pose block may hold (its
#: binary columns beside the session file, :mod:`hexcal.io.pose_block`, 137 bytes a pose with
#: no extra column: 411 MB at the limit). ``session import`` refuses a larger table before
#: the session is written, and every reader refuses a larger block: 3 million poses, a CSV of
#: about 540 MB, read by every command in well under 2 GB (docs/performance.md).
MAX_IMPORTED_POSES = 3_000_000
#: The most poses one step may ask for (the procedure file's ``recommended_poses`` and
#: ``min_poses``, and ``--poses-per-step``).
MAX_POSES_PER_STEP = 10_000
