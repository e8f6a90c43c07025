"""The guided session: one procedure step after another, driven by an operator (or a script).

This is the text UI's engine, kept free of any UI so that it is tested on its own and a
different front end can drive it. It owns the session file (saved after every change), the
procedure's steps and where the operator is in them, and the acquisition to record from:

* :meth:`GuidedSession.record` records one pose of the current step (the step's clamp checks
  run on it: a length clamp that gave way refuses the pose), :meth:`undo` sets the last one
  aside, :meth:`finish_step` runs the end-of-step check and moves on (or sets the step's poses
  aside and asks for it again), :meth:`skip_step` moves on without it;
* :meth:`live` reads the devices' latest samples without waiting, and says whether the clamp
  holds *now*: the clamped leg's encoder against the step's first pose for a length clamp, the
  live pose against the line or point the step's poses fit so far for a direction clamp;
* :meth:`conditioning` tells how well the step's poses so far determine the leg's points: the
  predicted 1σ of the platform and base points from the linear system and the noise, and the
  motion the poses have varied least; :meth:`suggestion` gives the next best pose
  (:mod:`hexcal.estimate.nbp`) on the geometry the step's poses estimate, once they determine it.

With a motion controller (the mock rig's), :meth:`clamp`, :meth:`move` and :meth:`release` do
the operator's hands' work; on a real robot the operator clamps and moves, and confirms.

A resumed session starts at the first step not marked done or skipped in the file, with the
poses already recorded for it — under the operator's clamp, which is still on. With a motion
controller (a simulated rig restarted) the clamp is gone, so a partly recorded clamped step is
set aside and starts again.

Once the procedure is done, :meth:`record_extra` records free poses beyond it — the poses a plan
asks for (:mod:`hexcal.diagnosis.plan`), which :meth:`move_to_pose` drives to on a motion
controller.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.acquire.acquisition import LegSample, PoseRefused, RecordedPose, TrackerSample
from hexcal.diagnosis.live_rank import LiveRanking
from hexcal.errors import HexcalError
from hexcal.estimate import nbp
from hexcal.model.noise import NoiseSigmas
from hexcal.model.robot import Robot
from hexcal.procedure import patterns, step_fit
from hexcal.procedure.recording import (
    BusStatus,
    ClampSlipped,
    Mover,
    Recorder,
    Step,
    StepCheck,
    StepRecorder,
    move_to_next_pose,
    per_pose_noise,
    reclamped_at_home,
)
from hexcal.procedure.session import PoseRecord, SessionFile, StepProgress
from hexcal.procedure.step_fit import NBP_MIN_POSES, Conditioning
from hexcal.vocabulary import Constraint


class GuidedError(HexcalError):
    """The operator asked for something the step does not allow now; the message says why."""


@dataclass(frozen=True)
class Refusal:
    """Why an operator's action cannot be done now: ``text``, one sentence, and ``remedy``, the
    action that would allow it (``"clamp"``, ``"record"``, ``"calibrate"``; None: none now)."""

    text: str
    remedy: str | None = None


@dataclass
class Live:
    """What the devices say now, and whether the clamp holds.

    ``position`` (3,) mm and ``rotvec_deg`` (3,) of the platform, None when the tracker has
    no pose; ``readings`` (6,) mm (NaN where missing); ``tracker_status`` and ``bus_status``
    one line each; ``clamp`` one line on the constraint (empty for a free step);
    ``clamp_ok`` False when the clamp is seen to give way."""

    position: np.ndarray | None
    rotvec_deg: np.ndarray | None
    readings: np.ndarray
    tracker_status: str
    bus_status: str
    clamp: str
    clamp_ok: bool


def pose_from_record(rec: PoseRecord) -> RecordedPose:
    """A :class:`RecordedPose` rebuilt from its session record (for a resumed step's checks)."""
    ts = [
        TrackerSample(
            s.t,
            None if s.position is None else np.array(s.position),
            None if s.quaternion is None else np.array(s.quaternion),
            float("nan") if s.rms_mm is None else s.rms_mm,
            s.fault,
        )
        for s in rec.tracker_samples
    ]
    ls = [
        LegSample(
            s.t,
            np.array([np.nan if v is None else v for v in s.readings], float),
            tuple(s.faults),
        )
        for s in rec.leg_samples
    ]
    return RecordedPose(
        rec.t,
        np.array(rec.position),
        np.array(rec.quaternion),
        np.array(rec.readings),
        ts,
        ls,
        notes=tuple(rec.notes),
    )


@dataclass(frozen=True)
class ExtraStep:
    """A step beyond the procedure (:meth:`GuidedSession.record_extra`): free poses, named."""

    name: str
    leg: int = 0
    constraint: Constraint = Constraint.FREE


class GuidedSession:
    """A procedure run by an operator, step by step, into ``sf`` (see module docstring).

    ``steps``: the expanded procedure; ``acquisition``: where poses come from (``record()`` and
    ``latest()``); ``mover``: a motion controller, or None when the operator moves the robot;
    ``platform_radius_mm``: |b_k| of the design, to scale orientation noise into mm;
    ``encoders``: the leg-encoder driver, for the bus status line (optional); ``clock_start``:
    the monotonic time session times count from."""

    def __init__(
        self,
        sf: SessionFile,
        steps: Sequence[Step],
        acquisition: Recorder,
        *,
        platform_radius_mm: float,
        mover: Mover | None = None,
        encoders: BusStatus | None = None,
        clamp_tolerance_mm: float = 0.02,
        clock_start: float = 0.0,
        on_event: Callable[[str], None] = lambda message: None,
        thermometer: Callable[[], float] | None = None,
    ):
        self.sf = sf
        self.thermometer = thermometer
        self._suggested: tuple | None = None  # (what it was computed for, the suggestion)
        #: The structure temperature the operator last entered (degC), for rigs without a
        #: thermometer: every pose recorded after it carries it, until the next entry.
        self.temperature_c: float | None = None
        self.steps = list(steps)
        self.acquisition = acquisition
        self.mover = mover
        self.encoders = encoders
        self.platform_radius_mm = platform_radius_mm
        self.clamp_tolerance_mm = clamp_tolerance_mm
        self.on_event = on_event
        self._sink = sf.recording_sink(clock_start)
        self.clamped = False
        self._clamp_reading: float | None = None  # the clamped leg's encoder when clamped
        self.index = 0
        self.recorder = StepRecorder(self.steps[0], clamp_tolerance_mm) if self.steps else None
        inst = getattr(sf.session, "instruments", None)
        #: The candidate effects ranked as poses come (the recording screen shows the leader)
        self.ranking = LiveRanking(
            sf.session.robot, None if inst is None else NoiseSigmas.from_instruments(inst)
        )
        self._restore()

    # -- where we are -----------------------------------------------------------------------
    def _restore(self) -> None:
        """Skip the steps the file marks done or skipped; reload the current step's poses."""
        finished = {p.step for p in self.sf.session.progress}
        self.index = next(
            (i for i, s in enumerate(self.steps) if s.name not in finished), len(self.steps)
        )
        if self.finished:
            self.recorder = None
            return
        self.recorder = StepRecorder(self.step, self.clamp_tolerance_mm)
        mine = [r for r in self.sf.session.poses if r.step == self.step.name]
        held = getattr(self.mover, "clamp_state", None)
        still_clamped = held is not None and (held.leg, held.constraint) == (
            self.step.leg,
            self.step.constraint,
        )
        if mine and self.step.leg and self.mover is not None and not still_clamped:
            # A motion controller starts unclamped (a simulated rig starts afresh): the step's
            # poses were taken under a clamp that is gone, so the step starts again.
            self.sf.set_aside_step(
                self.step.name,
                "the session was resumed on a motion controller that no longer holds this "
                "step's clamp: the step starts again",
            )
            return
        for rec in mine:
            self.recorder.accept(pose_from_record(rec))
        if self.recorder.poses and self.step.leg:
            self.clamped = True  # the operator's clamp is still on, as the poses were taken

    @property
    def finished(self) -> bool:
        return self.index >= len(self.steps)

    @property
    def step(self) -> Step:
        if self.finished:
            raise GuidedError("the procedure is finished: every step is done or skipped")
        return self.steps[self.index]

    @property
    def _rec(self) -> StepRecorder:
        """The current step's recorder (none once the procedure is finished)."""
        if self.recorder is None:
            raise GuidedError("the procedure is finished: every step is done or skipped")
        return self.recorder

    @property
    def n_poses(self) -> int:
        """Poses recorded in the current step."""
        return len(self.recorder.poses) if self.recorder else 0

    @property
    def can_finish(self) -> bool:
        return not self.finished and self.n_poses >= self.step.min_poses

    def refusal(self, action: str) -> Refusal | None:
        """Why the operator's ``action`` cannot be done now (None: it can). ``action`` names a
        method: ``clamp``, ``move``, ``record``, ``undo``, ``finish`` (:meth:`finish_step`),
        ``skip`` (:meth:`skip_step`), ``note``, ``temperature`` (:meth:`set_temperature`),
        ``suggest`` (:meth:`suggestion`: whether the step can have one yet). The
        methods raise :class:`GuidedError` with the same text; a front end greys the action out
        and says it when asked."""
        if action == "note":
            return None
        if action == "temperature":
            if self.thermometer is not None:
                return Refusal("this rig reads its own thermometer: the typed value is not used")
            return None
        if self.finished:
            return Refusal("the procedure is finished: every step is done or skipped", "calibrate")
        st, n = self.step, self.n_poses
        if action == "clamp":
            if not st.leg:
                return Refusal(f"{st.name} clamps no leg: move the platform and record", "record")
            if self.clamped:
                return Refusal(f"leg {st.leg} is already clamped ({st.constraint})")
        elif action == "move":
            if self.mover is None:
                return Refusal("no motion controller: move the platform with the robot's own")
            if st.leg and not self.clamped:
                return Refusal(f"clamp leg {st.leg} ({st.constraint}) first", "clamp")
        elif action == "record":
            if st.leg and not self.clamped:
                return Refusal(f"clamp leg {st.leg} ({st.constraint}) before recording", "clamp")
        elif action == "suggest":
            if not st.leg:
                return Refusal(f"{st.name} clamps no leg: no next best pose, spread the poses out")
            if n < NBP_MIN_POSES:
                return Refusal(
                    f"the next best pose needs {NBP_MIN_POSES} poses of this step ({n} so far)",
                    "record" if self.clamped else "clamp",
                )
        elif action == "undo":
            if not n:
                return Refusal(f"{st.name} has no pose to undo")
        elif action == "finish":
            if n < st.min_poses:
                more = st.min_poses - n
                return Refusal(
                    f"{st.name} needs at least {st.min_poses} pose"
                    + ("s" if st.min_poses > 1 else "")
                    + f" ({n} so far): record "
                    + ("one more" if more == 1 else f"{more} more"),
                    "record",
                )
        return None

    def _refuse(self, action: str) -> None:
        if (why := self.refusal(action)) is not None:
            raise GuidedError(why.text)

    # -- the operator's actions -----------------------------------------------------------------
    def clamp(self) -> str:
        """The leg is clamped (by the mock controller, or as the operator confirms)."""
        st = self.step
        if not st.leg:
            raise GuidedError(f"{st.name} clamps no leg")
        if not self.clamped:
            self._set_clamp()
        return self._say(f"leg {st.leg} clamped ({st.constraint})")

    def _set_clamp(self) -> None:
        st = self.step
        if self.mover is not None:
            self.mover.clamp(st.leg, st.constraint)
        self.clamped = True
        _, legs = self._latest()
        if legs is not None and np.isfinite(legs.readings[st.leg - 1]):
            self._clamp_reading = float(legs.readings[st.leg - 1])

    def home(self) -> str:
        """Move the platform home before a leg is clamped (motion controller only): where a leg
        is clamped decides the poses its clamp allows, and about home they reach every way
        within the joint limits; clamped far out (after a pose at the workspace's edge) they
        may reach none."""
        if self.mover is None:
            raise GuidedError("no motion controller: move the platform with the robot's own")
        if self.clamped:
            raise GuidedError(f"leg {self.step.leg} is clamped: release it first")
        self.mover.home()
        return self._say("moved home")

    def release(self) -> None:
        if self.mover is not None and self.clamped:
            self.mover.release()
        self.clamped = False
        self._clamp_reading = None

    def move(self) -> str:
        """Move the platform to the step's next pose (motion controller only); where the step's
        clamp, fresh, allows no pose, the leg is clamped again at home first
        (:func:`~hexcal.procedure.recording.move_to_next_pose`)."""
        self._refuse("move")
        mover, st = self.mover, self.step
        if mover is None:  # refused above: for the type checker
            raise GuidedError("no motion controller")

        def reclamp() -> None:
            self.release()
            self.home()
            self._set_clamp()
            self._say(reclamped_at_home(st))

        return move_to_next_pose(
            mover, st, self.n_poses, self.sf.session.robot, reclamp if self.clamped else None
        )

    def pattern_target(self) -> patterns.Target:
        """Where a pattern step's next pose is taken (:mod:`hexcal.procedure.patterns`)."""
        st = self.step
        if not st.pattern:
            raise GuidedError(f"{st.name} has no set targets: the operator chooses its poses")
        return patterns.target(st.pattern, self.sf.session.robot, self.n_poses, st.cycles)

    def record(self) -> tuple[bool, str]:
        """Record one pose of the current step: (recorded, operator message). Blocks for the
        still window. Refused poses are kept in the session file with their reason; record
        again *at the same pose* (the motion history between recorded poses is what
        direction-dependent effects such as backlash are fitted from)."""
        self._refuse("record")
        st = self.step
        try:
            pose = replace(self.acquisition.record(), temperature=self.temperature())
        except PoseRefused as exc:
            self._sink("refused", st, None, str(exc))
            return False, self._say(f"pose refused: {exc}")
        try:
            self._rec.accept(pose)
        except ClampSlipped as exc:
            self._sink("refused", st, pose, str(exc))
            return False, self._say(str(exc))
        self._sink("pose", st, pose, "")
        rot = Rotation.from_quat(pose.quaternion, scalar_first=True).as_matrix()
        self.ranking.add(pose.position, rot, pose.readings, pose.t, pose.temperature)
        # The notes name each flagged sample in full in the session file; here, how many.
        left_out = "; ".join(n.split(":")[0] for n in pose.notes)
        return True, self._say(
            f"{st.name}: pose {self.n_poses} recorded" + (f" ({left_out})" if left_out else "")
        )

    def undo(self) -> str:
        """Set the current step's last pose aside (kept in the file, out of the calibration)."""
        self._refuse("undo")
        self._rec.poses.pop()
        self.ranking.undo()
        if not self._rec.poses:
            self.recorder = StepRecorder(self.step, self.clamp_tolerance_mm)
        self.sf.undo_last_pose()
        return self._say(f"{self.step.name}: last pose set aside ({self.n_poses} left)")

    def finish_step(self, design: Robot | None = None) -> StepCheck:
        """End the step: its check runs; passed, the step is done and the next one starts;
        failed, its poses are set aside (kept, with the reason) and the step starts again. The
        check's message is the operator's sentence either way; a step ended below its
        recommended count says so, and why (``design``: to tell whether its poses already
        predict the step's target 1σ, see :meth:`target_met`)."""
        self._refuse("finish")
        st = self.step
        short = self._short_of_recommended(design)
        rec = self._rec
        check = rec.finish(per_pose_noise(rec.poses), self.platform_radius_mm)
        self.release()
        if not check.ok:
            for p in rec.poses:
                self._sink("set-aside", st, p, check.message)
            self.recorder = StepRecorder(st, self.clamp_tolerance_mm)
            self._say(check.message)
            return check
        words = (
            f"fit {check.rms_mm:.4f} mm RMS, noise predicts {check.expected_mm:.4f} mm"
            if np.isfinite(check.rms_mm)
            else ""
        )
        self.sf.add_progress(
            StepProgress(step=st.name, status="done", poses=self.n_poses, check=words)
        )
        said = self._say(
            f"{st.name} done: {self.n_poses} pose{'s' if self.n_poses != 1 else ''}"
            + (f" ({words})" if words else "")
            + (f" — {short}" if short else "")
        )
        self._advance()
        return replace(check, message=said)

    def _short_of_recommended(self, design: Robot | None) -> str:
        """Why the step ends below its recommended count, for the operator ("" when it does
        not)."""
        st, n = self.step, self.n_poses
        if n >= st.n_poses:
            return ""
        if design is not None and self.target_met(design):
            s = self.suggestion(design)
            return (
                f"{n} of {st.n_poses} recommended poses: the predicted 1σ "
                f"{s.sigma_before_mm:.3f} mm already meets the step's {st.target_sigma_mm:g} mm "
                "target"
                if s is not None
                else ""
            )
        return (
            f"ended at {n} of {st.n_poses} recommended poses (minimum {st.min_poses}): its "
            "points are less certain than the procedure plans"
        )

    def skip_step(self, reason: str = "skipped by the operator") -> str:
        """Move on without this step (its poses so far stay in the session)."""
        st = self.step
        self.release()
        self.sf.add_progress(
            StepProgress(step=st.name, status="skipped", poses=self.n_poses, check=reason)
        )
        self._advance()
        return self._say(f"{st.name} skipped")

    def _advance(self) -> None:
        self.index += 1
        self.recorder = None if self.finished else StepRecorder(self.step, self.clamp_tolerance_mm)

    def _say(self, message: str) -> str:
        self.on_event(message)
        return message

    # -- live ---------------------------------------------------------------------------------
    def _latest(self) -> tuple[TrackerSample | None, LegSample | None]:
        latest = getattr(self.acquisition, "latest", None)
        return latest() if latest else (None, None)

    def live(self) -> Live:
        """The devices' latest samples and the clamp monitor (never blocks)."""
        trk, legs = self._latest()
        pos = rv = None
        if trk is None:
            t_status = "no sample yet"
        elif trk.fault or trk.position is None:
            t_status = f"FAULT: {trk.fault or 'no pose'}"
        else:
            pos = np.asarray(trk.position)
            rv = Rotation.from_quat(trk.quaternion, scalar_first=True).as_rotvec(degrees=True)
            t_status = "tracking"
        readings = np.full(6, np.nan) if legs is None else np.asarray(legs.readings, float)
        if legs is None:
            b_status = "no reading set yet"
        elif legs.faults:
            b_status = f"FLAGGED: {legs.faults[0]}"
        else:
            b_status = "six positions"
        st = self.encoders.status() if self.encoders is not None else None
        if st is not None:
            b_status = f"{st['bus_state']}, {st['sets']} sets ({st['incomplete_sets']} flagged); {b_status}"
        clamp, ok = self._clamp_monitor(pos, rv, readings)
        return Live(pos, rv, readings, t_status, b_status, clamp, ok)

    def _clamp_monitor(
        self, pos: np.ndarray | None, rv: np.ndarray | None, readings: np.ndarray
    ) -> tuple[str, bool]:
        if self.finished:
            return "", True
        st = self.step
        if not st.leg:
            return "", True
        if not self.clamped:
            return f"leg {st.leg} not clamped yet", True
        k = st.leg - 1
        parts, ok = [], True
        poses = self._poses()
        tol = self._rec.clamp_tolerance_mm
        if st.constraint.clamps_length:
            ref = float(poses[0].readings[k]) if poses else self._clamp_reading
            if ref is not None and np.isfinite(readings[k]):
                d = float(readings[k] - ref)
                ok = abs(d) <= tol
                parts.append(
                    f"length {d:+.4f} mm since {'the first pose' if poses else 'clamped'}"
                    f" (±{tol:g})" + ("" if ok else " — SLIPPING")
                )
        if st.constraint.clamps_direction and pos is not None and len(poses) >= 4:
            rot = Rotation.from_rotvec(rv, degrees=True)
            off = step_fit.direction_offset(st, poses, pos, rot, readings[k])
            limit = step_fit.live_offset_limit_mm(st, poses, self.platform_radius_mm)
            good = off <= limit
            ok = ok and good
            what = "line" if st.constraint == Constraint.DIRECTION else "point"
            parts.append(
                f"{what} {off:.3f} mm off the step's fit (≤ {limit:.3f})"
                + ("" if good else " — CLAMP MOVED?")
            )
        return "; ".join(parts) or f"leg {st.leg} clamped ({st.constraint})", ok

    def _poses(self) -> list[RecordedPose]:
        """The current step's poses, one copy of the list: the text UI's recording worker
        appends to it from its thread while the screen reads it, and whatever is computed from
        them at once (:mod:`~hexcal.procedure.step_fit`) must count the same poses."""
        return list(self.recorder.poses) if self.recorder else []

    def conditioning(self, design_b: np.ndarray | None = None) -> Conditioning:
        """The predicted uncertainty of the current step's linear system
        (:func:`~hexcal.procedure.step_fit.conditioning`; ``design_b`` (6, 3) mm: the platform
        points for a length step's sphere fit)."""
        poses = self._poses()
        return step_fit.conditioning(
            self.step, poses, self.platform_radius_mm, self._hint(poses), design_b
        )

    def _hint(self, poses: list[RecordedPose]) -> str:
        """What to do next on the current step: its home pose, its pattern's next target, or
        the motion ``poses`` have varied least."""
        st = self.step
        if st.at_home:
            return "record the home pose"
        if st.pattern:
            return f"next: {self.pattern_target().label}"
        return step_fit.motion_hint(st, poses)

    def suggestion(self, design: Robot, n_candidates: int = 300) -> nbp.Suggestion | None:
        """The next best pose of the current clamped step (None before its poses determine the
        clamp, or on a free step). Every 5th is a space-filling one. Seeded by the pose count,
        so the same poses give the same suggestion — computed once for them (the screen, the
        target check and the mock operator all ask)."""
        poses = self._poses()
        key = (self.index, self.step, len(poses), poses[-1].t if poses else None, id(design))
        if self._suggested is None or self._suggested[0] != (key, n_candidates):
            found = step_fit.suggest(self.step, poses, design, n_candidates)
            self._suggested = ((key, n_candidates), found)
        return self._suggested[1]

    def target_met(self, design: Robot) -> bool:
        """The step has its minimum count and its poses already predict the step's target 1σ
        (``Step.target_sigma_mm``): more poses are not needed."""
        st = self.step
        if st.target_sigma_mm is None or self.n_poses < st.min_poses:
            return False
        s = self.suggestion(design)
        return s is not None and s.done

    def move_to_suggestion(self, s: nbp.Suggestion) -> str:
        """Follow a suggestion with the motion controller (the mock's: it holds the clamp)."""
        self.move_to_pose(s.position, s.rotation)
        return "moved to the suggested pose"

    def move_to_pose(self, position: np.ndarray, rotation: np.ndarray) -> str:
        """Drive the platform to a pose (``position`` (3,) mm, ``rotation`` (3, 3)) with the
        motion controller, as an operator follows one: a next best pose, a planned pose (the
        position the nearest a clamp allows). MotionError outside the limits."""
        if self.mover is None or not hasattr(self.mover, "move_near"):
            raise GuidedError("no motion controller that can follow a given pose: move by hand")
        self.mover.move_near(position, rotation)
        return "moved to the pose"

    def record_extra(self, name: str) -> tuple[bool, str]:
        """Record one free pose beyond the procedure, once it is finished, under the step
        ``name`` (a plan's poses: ``plan``): (recorded, operator message). Blocks for the still
        window; a refused pose is kept in the file with its reason, as :meth:`record` does."""
        if not self.finished:
            raise GuidedError(
                f"{self.step.name} is under way: finish or skip the procedure's steps first"
            )
        if self.clamped:
            raise GuidedError("a leg is clamped: poses beyond the procedure are free ones")
        step = ExtraStep(name)
        try:
            pose = replace(self.acquisition.record(), temperature=self.temperature())
        except PoseRefused as exc:
            self._sink("refused", step, None, str(exc))
            return False, self._say(f"pose refused: {exc}")
        self._sink("pose", step, pose, "")
        rot = Rotation.from_quat(pose.quaternion, scalar_first=True).as_matrix()
        self.ranking.add(pose.position, rot, pose.readings, pose.t, pose.temperature)
        n = sum(r.step == name for r in self.sf.session.poses)
        return True, self._say(f"{name}: pose {n} recorded")

    # -- what was recorded ------------------------------------------------------------------------
    def set_aside_count(self) -> int:
        return len(self.sf.session.set_aside)

    def note(self, text: str) -> str:
        """Keep the operator's note in the session file (with the time)."""
        text = text.strip()
        if not text:
            raise GuidedError("the note is empty: type what you want to keep, then Enter")
        self.sf.add_note(text)
        return self._say(f"note kept: {text}")

    def temperature(self) -> float | None:
        """The structure temperature for the next pose (degC): the thermometer's reading, else
        what the operator last entered, else None (unknown)."""
        if self.thermometer is not None:
            return float(self.thermometer())
        return self.temperature_c

    def set_temperature(self, text: str) -> str:
        """The operator read the structure's temperature (degC, as typed): every pose from now
        on carries it, so the diagnosis can see thermal expansion."""
        try:
            value = float(text.strip().replace(",", "."))
        except ValueError:
            raise GuidedError(
                f"{text.strip()!r} is not a temperature: type degrees Celsius, e.g. 21.5"
            ) from None
        if not -40.0 <= value <= 80.0:
            raise GuidedError(
                f"{value:g} °C is outside -40..80 °C: type the structure's temperature in degrees Celsius"
            )
        if self.thermometer is not None:
            raise GuidedError("this rig reads its own thermometer: the typed value is not used")
        self.temperature_c = value
        self.sf.add_note(f"structure temperature {value:g} °C (entered by the operator)")
        before = sum(r.temperature is None for r in self.sf.session.poses)
        return self._say(
            f"structure temperature {value:g} °C: the next poses carry it"
            + (
                f" ({before} pose{'s' if before > 1 else ''} before it "
                f"{'have' if before > 1 else 'has'} none, so the measurement table leaves "
                "temperature out: enter it before the first pose to fit thermal expansion)"
                if before
                else ""
            )
        )

    def summary(self) -> list[tuple[str, str, int, int, int]]:
        """(step, state, poses, min, recommended) for every step; state 'done', 'skipped',
        'now' or ''."""
        prog = {p.step: p for p in self.sf.session.progress}
        counts: dict[str, int] = {}
        for r in self.sf.session.poses:
            counts[r.step] = counts.get(r.step, 0) + 1
        out: list[tuple[str, str, int, int, int]] = []
        for i, s in enumerate(self.steps):
            state = prog[s.name].status if s.name in prog else ("now" if i == self.index else "")
            out.append((s.name, state, counts.get(s.name, 0), s.min_poses, s.n_poses))
        return out
