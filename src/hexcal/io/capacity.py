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
#: An imported pose's bytes in the session file at the least (no raw samples: its table row as
#: JSON; the example session of 184 poses took 93,607 bytes with its robot, 509 a pose).
IMPORTED_POSE_BYTES = 480
#: The most poses an imported table may bring: more cannot fit in a session file, and are
#: refused before anything is built or written (1,118,481 poses).
MAX_IMPORTED_POSES = MAX_SESSION_BYTES // IMPORTED_POSE_BYTES
#: The most poses one step may ask for (the procedure file's ``recommended_poses`` and
#: ``min_poses``, and ``--poses-per-step``).
MAX_POSES_PER_STEP = 10_000
