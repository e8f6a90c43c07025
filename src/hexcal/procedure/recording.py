"""Recording a calibration session: the procedure's steps, the clamp checks, the recorded poses.

A *procedure* is an ordered list of :class:`Step`: for each leg, its clamped steps (direction —
Type I; direction+length — Type II; length — Type III), then free poses. A step's poses are
recorded one by one through :class:`~hexcal.acquire.acquisition.Acquisition`; :class:`StepRecorder`
checks, as they come, that the clamp holds:

* a *length* clamp (Types II and III) holds the leg's length, so that leg's encoder must read
  the same at every pose of the step: a pose whose clamped-leg reading departs from the step's
  first one by more than ``clamp_tolerance_mm`` is refused (:class:`ClampSlipped`) — the clamp
  is slipping;
* a *direction* clamp (Types I and II) cannot be checked pose by pose without the geometry, but
  at the end of the step its poses must fit the step's linear model (Type I: one line through
  the base point, eq. ``P_i + R_i b − a − ρ_i u = 0``; Type II: one fixed point, ``P_i + R_i b =
  C``): :meth:`StepRecorder.finish` compares the fit's residual with what the noise predicts and
  fails the step if it is far above (the clamp slipped, or the platform was not clamped).

Nothing is lost: refused poses and the poses of a failed step are kept, with the reason, in
:attr:`SessionRecording.rejected`; only accepted poses go into the measurement table.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.acquire.acquisition import LegSample, PoseRefused, RecordedPose, TrackerSample
from hexcal.errors import DeviceError
from hexcal.estimate.solvers.direct import type_i_system, type_ii_system
from hexcal.estimate.solvers.linalg import lstsq
from hexcal.io.measurements import Measurements
from hexcal.model.instruments import EncoderNoise, Instruments, TrackerNoise
from hexcal.model.robot import Robot
from hexcal.vocabulary import LEG_CONSTRAINTS, Constraint, counted

#: The clamped steps of one leg, in the order an operator records them.
LEG_STEPS = LEG_CONSTRAINTS

#: A step fails its end check when its fit residual RMS exceeds this many times what the noise
#: predicts *and* ``MIN_SLIP_MM``: the ratio alone would flag unmodelled millimicron effects on
#: a very quiet tracker; the floor keeps the check about clamps, not about encoder physics.
SLIP_RATIO = 4.0
MIN_SLIP_MM = 0.03


@dataclass(frozen=True)
class Step:
    """One step of a procedure: ``leg`` 1..6 clamped as ``constraint`` (0 and free: none),
    ``n_poses`` poses to record (the recommended count), at least ``min_poses``.

    ``instruction`` is the operator's text; ``tolerance_mm`` how far the length clamp may give
    (None: the recorder's default); ``checks`` which clamp checks run (None: every check the
    constraint allows — ``clamp-length`` for a length clamp, ``step-fit`` for a direction
    clamp). ``constraint`` may be given as its text ("direction"...)."""

    leg: int
    constraint: Constraint
    n_poses: int
    instruction: str = ""
    min_poses: int = 1
    tolerance_mm: float | None = None
    checks: tuple[str, ...] | None = None
    at_home: bool = False  #: its poses are taken at the robot's home pose
    #: The predicted 1σ (mm) of the point that matters at which the step has enough poses: the
    #: next-best-pose suggestions stop there (None: no target, suggest until the count).
    target_sigma_mm: float | None = None
    #: The targets it visits (:mod:`hexcal.procedure.patterns`: ``iso9283``, ``iso230-2``) and
    #: how many cycles of them; None: poses where the operator chooses.
    pattern: str | None = None
    cycles: int | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "constraint", Constraint(self.constraint))

    def runs(self, check: str) -> bool:
        """Whether ``check`` runs for this step."""
        c = self.constraint
        allowed = {"clamp-length": c.clamps_length, "step-fit": c.clamps_direction}[check]
        return allowed and (self.checks is None or check in self.checks)

    @property
    def name(self) -> str:
        if self.pattern:
            return self.pattern
        if self.leg == 0:
            return "home" if self.at_home else "free"
        return f"leg{self.leg}-{self.constraint}"


def standard_procedure(
    n_direction: int = 8, n_both: int = 8, n_length: int = 8, n_free: int = 40
) -> list[Step]:
    """Every leg's three clamped steps, then the free poses (steps with 0 poses left out)."""
    counts = {
        Constraint.DIRECTION: n_direction,
        Constraint.DIRECTION_LENGTH: n_both,
        Constraint.LENGTH: n_length,
    }
    steps = [Step(leg, c, counts[c]) for leg in range(1, 7) for c in LEG_STEPS if counts[c] > 0]
    if n_free > 0:
        steps.append(Step(0, Constraint.FREE, n_free))
    return steps


class ClampSlipped(PoseRefused):
    """A length clamp let its leg move: the pose is refused; re-tighten and repeat the step."""


@dataclass
class StepCheck:
    """The end-of-step check: ``ok``, the fit residual RMS and the noise prediction (mm), and
    an operator sentence."""

    ok: bool
    rms_mm: float
    expected_mm: float
    message: str


@dataclass
class NoiseLevels:
    """Per-sample noise, one standard deviation: tracker position mm (per axis), orientation
    deg, encoder reading mm."""

    position_mm: float
    orientation_deg: float
    reading_mm: float


def still_window_noise(poses: Sequence[RecordedPose]) -> NoiseLevels:
    """Per-sample noise pooled from the scatter of the raw samples inside each still window.

    Valid for white noise; a tracker whose frames are correlated makes it optimistic, which
    the refinement's χ² then shows."""
    dp, dth, dr = [], [], []
    for p in poses:
        pos = np.array([s.position for s in p.good_tracker_samples])
        dp.append(pos - pos.mean(axis=0))
        rot = Rotation.from_quat(
            np.array([s.quaternion for s in p.good_tracker_samples]), scalar_first=True
        )
        dth.append((Rotation.from_quat(p.quaternion, scalar_first=True).inv() * rot).as_rotvec())
        rho = np.array([s.readings for s in p.good_leg_samples])
        dr.append(rho - rho.mean(axis=0))

    def pooled(devs: list[np.ndarray]) -> float:
        ss = sum(float(np.sum(d**2)) for d in devs)
        dof = sum((len(d) - 1) * d.shape[1] for d in devs)
        return float(np.sqrt(ss / dof)) if dof > 0 else float("nan")

    return NoiseLevels(pooled(dp), float(np.rad2deg(pooled(dth))), pooled(dr))


@dataclass
class AcceptedPose:
    """A pose that went into the measurement table, with the step it belongs to."""

    step: Step
    pose: RecordedPose


@dataclass
class RejectedPose:
    """A pose that did not: refused at recording (``pose`` None unless it was recorded) or
    recorded in a step that then failed its check. ``reason`` is the operator message."""

    step: Step
    reason: str
    pose: RecordedPose | None = None


class StepRecorder:
    """Collects one step's poses and checks that its clamp holds (see module docstring)."""

    def __init__(self, step: Step, clamp_tolerance_mm: float = 0.02):
        self.step = step
        self.clamp_tolerance_mm = (
            step.tolerance_mm if step.tolerance_mm is not None else clamp_tolerance_mm
        )
        self.poses: list[RecordedPose] = []
        self._clamped_reading: float | None = None

    @property
    def done(self) -> bool:
        return len(self.poses) >= self.step.n_poses

    def accept(self, pose: RecordedPose) -> None:
        """Add a recorded pose, or raise :class:`ClampSlipped` if the length clamp moved."""
        if self.step.runs("clamp-length"):
            k = self.step.leg - 1
            reading = float(pose.readings[k])
            if self._clamped_reading is None:
                self._clamped_reading = reading
            elif abs(reading - self._clamped_reading) > self.clamp_tolerance_mm:
                raise ClampSlipped(
                    f"leg {self.step.leg} is clamped in length but its encoder moved "
                    f"{reading - self._clamped_reading:+.3f} mm since the step's first pose "
                    f"(allowed ±{self.clamp_tolerance_mm:g} mm): the clamp is slipping — "
                    "re-tighten it and repeat this step"
                )
        self.poses.append(pose)

    def finish(self, noise: NoiseLevels, platform_radius_mm: float) -> StepCheck:
        """The end-of-step check of a direction clamp (always ok for length-only and free).

        ``noise`` is per recorded pose (already averaged over its still window);
        ``platform_radius_mm`` (|b_k|) scales the orientation noise into mm."""
        c = self.step.constraint
        if not self.step.runs("step-fit") or len(self.poses) < 4:
            return StepCheck(True, float("nan"), float("nan"), "")
        P = np.array([p.position for p in self.poses])
        R = Rotation.from_quat(
            np.array([p.quaternion for p in self.poses]), scalar_first=True
        ).as_matrix()
        if c == Constraint.DIRECTION:
            rho = np.array([p.readings[self.step.leg - 1] for p in self.poses])
            A, y = type_i_system(P, R, rho)
            what = "one clamped direction"
        else:
            A, y = type_ii_system(P, R)
            what = "one clamped point"
        x = lstsq(A, y)
        res = A @ x - y
        dof = max(len(y) - A.shape[1], 1)
        rms = float(np.sqrt(np.sum(res**2) / dof))
        expected = float(
            np.sqrt(
                noise.position_mm**2
                + (np.deg2rad(noise.orientation_deg) * platform_radius_mm) ** 2
                + (noise.reading_mm**2 if c == Constraint.DIRECTION else 0.0)
            )
        )
        ok = not (rms > SLIP_RATIO * expected and rms > MIN_SLIP_MM)
        msg = (
            ""
            if ok
            else f"{self.step.name}: the poses do not fit {what} (residual {rms:.3f} mm RMS, the "
            f"noise predicts {expected:.3f} mm): the clamp slipped or was not tight — its poses "
            "are set aside; re-clamp and repeat the step"
        )
        return StepCheck(ok, rms, expected, msg)


@dataclass
class SessionRecording:
    """The accepted poses in recording order, and everything rejected, with reasons."""

    accepted: list[AcceptedPose] = field(default_factory=list)
    rejected: list[RejectedPose] = field(default_factory=list)
    checks: list[tuple[Step, StepCheck]] = field(default_factory=list)

    def measurements(self) -> Measurements:
        """The measurement table of the accepted poses; t in s from the first pose."""
        if not self.accepted:
            raise ValueError("no pose has been recorded yet")
        poses = [a.pose for a in self.accepted]
        t = np.array([p.t for p in poses])
        return Measurements.from_arrays(
            np.array([p.position for p in poses]),
            np.array([p.quaternion for p in poses]),
            np.array([p.readings for p in poses]),
            leg=np.array([a.step.leg for a in self.accepted]),
            constraint=np.array([a.step.constraint for a in self.accepted], dtype=object),
            step=np.array([a.step.name for a in self.accepted], dtype=object),
            t=np.round(t - t[0], 6),
        )

    def noise(self) -> NoiseLevels:
        """Per-sample noise pooled over every accepted pose's still window."""
        return still_window_noise([a.pose for a in self.accepted])

    def instruments(self) -> Instruments:
        """The noise of the recorded (window-averaged) poses, as instruments.json states it
        (:func:`window_instruments`)."""
        inst = window_instruments([a.pose for a in self.accepted])
        if inst is None:
            raise ValueError("the recorded poses carry no still-window samples to estimate noise")
        return inst


class Recorder(Protocol):
    def record(self) -> RecordedPose: ...


class LiveRecorder(Recorder, Protocol):
    """A recorder that also shows the last samples as they arrive (the operator's live view)."""

    def latest(self) -> tuple[TrackerSample | None, LegSample | None]: ...


class MotionError(DeviceError):
    """The motion controller (a :class:`Mover`) cannot do what was asked; the message says
    why. Raised by any controller — the mock's (:mod:`hexcal.mock_hw.motion`) or a real one."""


#: What :func:`move_to_next_pose` says of a plain move to a step's next pose.
MOVED_ON = "moved to the next pose"


def reclamped_at_home(step: Step) -> str:
    """What is said where a step's fresh clamp allowed no pose and the leg was clamped again
    at home (:func:`move_to_next_pose`)."""
    return (
        f"{step.name}: leg {step.leg}'s clamp allowed no pose within the limits where it was "
        "set: released, moved home and clamped again"
    )


def move_to_next_pose(
    mover: Mover,
    step: Step,
    n_recorded: int,
    robot: Robot | None,
    reclamp: Callable[[], None] | None,
) -> str:
    """Move the platform to ``step``'s next pose, ``n_recorded`` of its poses being recorded:
    home for a step at home, the set target of a pattern step (computed from ``robot``), else
    the mover's next pose under the clamp. Return the operator's sentence.

    Clamped where the last pose left the platform, at the workspace's edge, a clamp may allow
    no pose within the joint limits and the legs' stroke (the mover's ``next_pose`` raises
    :class:`MotionError`). As an operator would, ``reclamp()`` then releases the clamp, moves
    the platform home and clamps the leg there, and the move is tried once more
    (:func:`reclamped_at_home` says so). Pass ``reclamp=None`` where that is not allowed:
    once a pose is recorded, it fixes where the clamp is. :func:`record_procedure` and
    :meth:`~hexcal.procedure.guided.GuidedSession.move` both move through this."""
    if step.at_home:
        mover.home()
        return "moved home"
    if step.pattern:
        from hexcal.procedure import patterns

        if robot is None:
            raise ValueError(f"{step.name} visits targets computed from the robot: pass it")
        return patterns.move_to(
            mover, patterns.target(step.pattern, robot, n_recorded, step.cycles)
        )
    try:
        mover.next_pose()
    except MotionError:
        if reclamp is None or n_recorded:
            raise
        reclamp()
        mover.next_pose()
        return reclamped_at_home(step)
    return MOVED_ON


class BusStatus(Protocol):
    """A leg-encoder driver that reports its bus: ``status()`` holds at least ``bus_state``,
    ``sets`` and ``incomplete_sets`` (see :meth:`hexcal.drivers.can_encoders.LegEncoders.status`)."""

    def status(self) -> dict[str, Any]: ...


class Mover(Protocol):
    def clamp(self, leg: int, constraint: str) -> object: ...
    def release(self) -> None: ...
    def next_pose(self) -> tuple[np.ndarray, np.ndarray]: ...
    def home(self) -> None: ...


@dataclass
class RunSettings:
    """How the scripted run behaves: wait ``settle_s`` after each move; retry a refused pose
    up to ``retries`` times (a new still window at the same pose; then the run stops with
    :class:`~hexcal.acquire.acquisition.PoseRefused`, its poses kept); repeat a step whose clamp check
    failed up to ``step_repeats`` times; ``clamp_tolerance_mm`` as in :class:`StepRecorder`."""

    settle_s: float = 0.05
    retries: int = 10
    step_repeats: int = 2
    clamp_tolerance_mm: float = 0.02


def record_procedure(
    acquisition: Recorder,
    mover: Mover,
    steps: Sequence[Step],
    platform_radius_mm: float,
    settings: RunSettings | None = None,
    on_event: Callable[[str], None] = lambda message: None,
    on_clamp: Callable[[Step, int], None] = lambda step, attempt: None,
    on_record: Callable[[str, Step, RecordedPose | None, str], None] | None = None,
    design: Robot | None = None,
) -> SessionRecording:
    """Run a procedure end to end with a motion controller doing the operator's moves.

    For each step: clamp, move and record ``n_poses`` poses, release, check; a failed step is
    set aside (its poses into ``rejected``) and repeated. ``on_clamp(step, attempt)`` runs just
    after the clamp is set (tests inject a slip there). ``on_event`` receives one operator
    sentence per thing that happened. ``on_record(kind, step, pose, reason)`` is told of every
    pose as it happens, so a session file can be saved after each: kind ``"pose"`` (recorded,
    pose given), ``"refused"`` (not recorded, pose None) and ``"set-aside"`` (a recorded pose
    of a step that then failed; once per pose, in recording order). ``design``: the robot a
    pattern step's targets are computed from (needed only for those)."""
    settings = settings or RunSettings()
    session = SessionRecording()
    tell = on_record or (lambda kind, step, pose, reason: None)
    for step in steps:
        for attempt in range(settings.step_repeats + 1):
            rec = StepRecorder(step, settings.clamp_tolerance_mm)
            if step.leg:
                mover.clamp(step.leg, step.constraint)
                on_event(f"{step.name}: leg {step.leg} clamped ({step.constraint})")
            on_clamp(step, attempt)
            failed = _record_step(
                acquisition, mover, rec, session, settings, on_event, tell, design
            )
            if step.leg:
                mover.release()
            if failed is None:
                check = rec.finish(per_pose_noise(rec.poses), platform_radius_mm)
                session.checks.append((step, check))
                failed = None if check.ok else check.message
            if failed is None:
                session.accepted += [AcceptedPose(step, p) for p in rec.poses]
                on_event(f"{step.name}: {counted(len(rec.poses), 'pose')} recorded")
                break
            session.rejected += [RejectedPose(step, failed, p) for p in rec.poses]
            for p in rec.poses:
                tell("set-aside", step, p, failed)
            on_event(failed)
        else:
            raise PoseRefused(
                f"{step.name} failed {settings.step_repeats + 1} times; last: {failed} — the "
                "recorded poses are kept; fix the clamp before going on"
            )
    return session


def _record_step(
    acq, mover, rec: StepRecorder, session, settings, on_event, tell, design=None
) -> str | None:
    """Record one step's poses; the reason the step must be repeated, or None."""
    step = rec.step

    def reclamp() -> None:
        mover.release()
        mover.home()
        mover.clamp(step.leg, step.constraint)
        on_event(reclamped_at_home(step))

    while not rec.done:
        move_to_next_pose(mover, step, len(rec.poses), design, reclamp if step.leg else None)
        time.sleep(settings.settle_s)
        for _ in range(settings.retries + 1):
            try:
                pose = acq.record()
            except PoseRefused as exc:  # timing glitch, motion: same pose, new window
                session.rejected.append(RejectedPose(rec.step, str(exc)))
                tell("refused", rec.step, None, str(exc))
                on_event(f"{rec.step.name}: pose refused: {exc}")
                continue
            try:
                rec.accept(pose)
            except ClampSlipped as exc:
                session.rejected.append(RejectedPose(rec.step, str(exc), pose))
                tell("refused", rec.step, pose, str(exc))
                return str(exc)
            tell("pose", rec.step, pose, "")
            break
        else:
            # A device problem, not a clamp problem: the step's good poses stay; stop here so the
            # operator can fix the device and resume (the session file has everything so far).
            raise PoseRefused(
                f"{rec.step.name}: a pose was refused {settings.retries + 1} times in a row; last: "
                f"{session.rejected[-1].reason} — fix the device, then resume the session"
            )
    return None


def per_pose_noise(poses: Sequence[RecordedPose]) -> NoiseLevels:
    """The noise (1σ) of window-averaged poses, from the scatter inside their own windows."""
    lv = still_window_noise(poses)
    n_t = float(np.mean([len(p.good_tracker_samples) for p in poses]))
    n_l = float(np.mean([len(p.good_leg_samples) for p in poses]))
    return NoiseLevels(
        lv.position_mm / np.sqrt(n_t),
        lv.orientation_deg / np.sqrt(n_t),
        lv.reading_mm / np.sqrt(n_l),
    )


def window_instruments(poses: Sequence[RecordedPose]) -> Instruments | None:
    """instruments.json's noise of window-averaged poses: per-sample levels from the scatter
    in their still windows divided by √(samples per window) (:func:`per_pose_noise`). None
    when the poses carry no raw samples (an imported table) or too few to tell."""
    if not poses or not all(p.tracker_samples and p.leg_samples for p in poses):
        return None
    lv = per_pose_noise(poses)
    levels = [lv.position_mm, lv.orientation_deg, lv.reading_mm]
    # Beyond instruments.json's bounds (1000 mm, 180°) the windows held no still pose at all.
    if not (
        np.isfinite(levels).all()
        and max(lv.position_mm, lv.reading_mm) <= 1000.0
        and lv.orientation_deg <= 180.0
    ):
        return None
    return Instruments(
        tracker=TrackerNoise(
            position_sigma_mm=lv.position_mm, orientation_sigma_deg=lv.orientation_deg
        ),
        encoders=EncoderNoise(reading_sigma_mm=lv.reading_mm),
        source="estimated from the still windows of the recorded poses",
    )
