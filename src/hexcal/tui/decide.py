"""The decide step: where the diagnosis offers a plan (look-alikes, or an effect the poses cannot
tell from the geometry), record the planned poses and watch the question get decided.

The poses are planned as ``hexcal plan`` plans them (:func:`hexcal.app.commands.plan.
plan_session`); the operator is guided to each as the recording screen guides to the next best
pose (the motion from the last pose, the leg readings it should give; ``g`` drives there on the
mock rig), records it through the rig's drivers (``r``; ``a``: the mock operator does every
pose), and the diagnosis runs again after each. The table shows the two hypotheses' χ² drawing
apart; the step ends when the question is decided at the verdict's confidence
(:mod:`hexcal.diagnosis.decide`) or when the plan is spent, and says which. Every pose is saved
in the session file (step ``plan``) as it is recorded.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation
from textual import work
from textual.binding import Binding
from textual.containers import VerticalScroll
from textual.content import Content
from textual.widgets import Header, Static

from hexcal.diagnosis.plan_offer import Offer
from hexcal.estimate.nbp import motion_text
from hexcal.procedure.guided import GuidedError
from hexcal.procedure.recording import MotionError
from hexcal.tui.fit import reflow
from hexcal.tui.screen import Foot, HexcalScreen
from hexcal.tui.working import Working
from hexcal.vocabulary import counted

#: The step name the planned poses are recorded under.
PLAN_STEP = "plan"
#: Rows of the χ² table on a short screen (the session's, a gap, the latest).
SHORT_ROWS = 6
#: Refused recordings of one pose after which the mock operator stops.
MAX_REFUSED = 5


class DecideScreen(HexcalScreen):
    """Record the poses planned for ``offer`` (see module docstring); ``diagnosis``: the one
    that offered it, whose model (``held`` effects added) every new diagnosis keeps."""

    BINDINGS = [
        Binding("g", "go", "go there"),
        Binding("r", "record", "record"),
        Binding("a", "auto", "auto"),
        Binding("escape", "back", "back"),
        Binding("q", "app.quit", "quit"),
    ]

    def __init__(self, offer: Offer, diagnosis: Any, held: tuple[str, ...]) -> None:
        super().__init__()
        self.offer, self.first, self.held = offer, diagnosis, held
        self.plan: Any = None
        self.busy = True
        self.auto_running = False
        self._stop_auto = False
        #: The planned poses recorded (each one recorded once; the plan's order)
        self.recorded = 0
        #: (poses recorded, Standing, the diagnosis' verdict) after each diagnosis
        self.rows: list[tuple[int, Any, str]] = []
        self.ended: str | None = None  # "decided" or "spent"
        #: What each box shows: plain text (wrapped to the width by reflow), and its style
        self._texts: dict[str, tuple[str, str]] = {}

    # -- layout ---------------------------------------------------------------------------------
    def compose(self):
        yield Header()
        yield Foot()
        yield Working(id="working")
        # What to do now first, then the χ² pose by pose, then the plan's figures: at 80×24
        # the action and the table are seen, the figures below them scroll.
        with VerticalScroll(id="decide-scroll"):
            yield Static("", id="decide-next")
            yield Static("", id="decide-table")
            yield Static("", id="decide-said")
            yield Static("", id="decide-head")

    def on_mount(self) -> None:
        from hexcal.diagnosis.decide import standing

        self.query_one("#decide-scroll").focus()
        self.rows.append((0, standing(self.first, self.offer), str(self.first.verdict)))
        self._working = self.query_one(Working)
        self._working.start(f"planning {counted(self.offer.n_planned, 'pose')}")
        self._plan()

    def on_resize(self) -> None:
        # The table's rows depend on the height, the wrapping on the width.
        self.call_after_refresh(self._show if self.rows else self._fit)

    def _fit(self) -> None:
        width = max(20, self.query_one("#decide-scroll").size.width - 4)
        for box, (text, style) in self._texts.items():
            self.query_one(box, Static).update(Content.styled(reflow(text, width), style))

    # -- planning -------------------------------------------------------------------------------
    @property
    def _guided(self) -> Any:
        g = self.hexcal.guided
        if g is None or self.hexcal.procedure is None:
            raise RuntimeError("the decide step needs a guided session: none is open")
        return g

    def _inputs(self) -> Any:
        """The workflow's inputs of the session, every pose so far."""
        from hexcal.app.workflow import session_inputs

        g = self._guided
        return session_inputs(g.sf.session, g.sf.path)

    @work(thread=True, exclusive=True, group="compute")
    def _plan(self) -> None:
        from hexcal.app.commands.plan import plan_session

        o = self.offer
        try:
            inp = self._inputs()
            plan = plan_session(
                inp,
                self.hexcal.procedure.model,  # type: ignore[union-attr]
                self.held,
                o.n_planned,
                (o.hypotheses[0], o.hypotheses[1]) if o.kind == "separate" else None,
                o.hypotheses[0] if o.kind == "resolve" else None,
            )
        except (ValueError, np.linalg.LinAlgError) as exc:
            self.hexcal.post(self._failed, f"cannot plan: {exc}")
            return
        self.hexcal.post(self._planned, plan)

    def _planned(self, plan: Any) -> None:
        from hexcal.app.commands.plan import plan_lines

        self._working.stop()
        self.plan = plan
        self.busy = False
        a, b = self.rows[0][1].hypotheses
        head = (
            f"The plan ({self.offer.text()}): {counted(len(plan.meas), 'pose')}, free (no leg "
            f"clamped); the diagnosis runs again after each. Δχ²: χ² {b} less χ² {a} (> 0: "
            f"{a} fits better)."
        )
        self._texts["#decide-head"] = ("\n".join([head, *plan_lines(plan)]), "")
        self._show()

    def _failed(self, msg: str) -> None:
        self._working.stop()
        self.busy = self.auto_running = False
        self.status(msg, "red")
        self.refresh_bindings()

    # -- display --------------------------------------------------------------------------------
    def _show(self) -> None:
        a, b = self.rows[0][1].hypotheses
        wa, wb = max(10, len(a) + 4), max(10, len(b) + 4)
        lines = [
            f"{'poses':>5} {'χ² ' + a:>{wa}} {'χ² ' + b:>{wb}} {'Δχ²':>8}  diagnosis",
        ]
        rows = self.rows
        if self.has_class("-short") and len(rows) > SHORT_ROWS:
            # 80×24: the session's row and the latest, so the last stays above the fold.
            rows = [rows[0], *rows[-(SHORT_ROWS - 2) :]]
        for i, (n, st, verdict) in enumerate(rows):
            if i == 1 and n > 1:
                lines.append(f"{'⋮':>5}")
            ca, cb = st.chi2
            lines.append(f"{n:>5} {ca:>{wa}.1f} {cb:>{wb}.1f} {st.delta_chi2:>+8.1f}  {verdict}")
        last = self.rows[-1][1]
        self._texts["#decide-table"] = ("\n".join(lines), "")
        self._texts["#decide-said"] = (last.said, "green" if last.decided else "yellow")
        self._texts["#decide-next"] = self._next_text()
        self._fit()
        self.refresh_bindings()

    def _next_text(self) -> tuple[str, str]:
        """What to do now, and its style: the next planned pose, or how the step ended."""
        plan = self.plan
        if self.ended == "decided":
            return (
                f"Decided after {counted(self.recorded, 'planned pose')} of {len(plan.meas)}: "
                f"{self.rows[-1][1].words}. Escape: back to the diagnosis, on every pose.",
                "bold green",
            )
        if self.ended == "spent":
            return (
                f"Plan spent: all {len(plan.meas)} planned poses recorded, and the question is "
                "still open (below). Escape: back to the diagnosis, on every pose.",
                "bold yellow",
            )
        if plan is None:
            return "", ""
        k = self.recorded
        if k >= len(plan.meas):  # the last diagnosis failed (the status line says why)
            return "Every planned pose is recorded. Escape: back to the diagnosis.", "bold"
        P, R = plan.meas.position[k], plan.meas.rotations.as_matrix()[k]
        last = self._guided.sf.session.poses[-1]
        R_last = Rotation.from_quat(last.quaternion, scalar_first=True).as_matrix()
        move = motion_text(np.asarray(last.position), R_last, P, R)
        legs = " ".join(f"{x:.3f}" for x in plan.meas.readings[k])
        mover = self._guided.mover is not None
        keys = "g goes there, r records, a does every pose" if mover else "r records there"
        return (
            _schedule_text(plan, k)
            + f"Planned pose {k + 1} of {len(plan.meas)}: {move}; the legs should read {legs} mm "
            f"— {keys}",
            "bold",
        )

    # -- actions --------------------------------------------------------------------------------
    def why_not(self, action: str) -> str | None:
        if action in ("back", "app.quit"):
            return None
        if self.plan is None:
            return "planning the poses: wait for the plan"
        if self.ended is not None:
            return f"the decide step has ended ({self.ended}): Escape, back to the diagnosis"
        if self.recorded >= len(self.plan.meas):
            return "every planned pose is recorded: Escape, back to the diagnosis"
        if action == "auto":
            if self._guided.mover is None:
                return "no motion controller: the mock operator needs one — go and record by hand"
            if self.busy and not self.auto_running:
                return "recording a pose: wait for it"
            return None  # while it runs, a stops it
        if self.busy:
            return (
                "the mock operator is at work: a stops it"
                if self.auto_running
                else "recording and diagnosing a pose: wait for it"
            )
        if action == "go" and self._guided.mover is None:
            return "no motion controller: move the platform to the planned pose by hand"
        return None

    def hidden(self, action: str) -> bool:
        """Out of the key bar: the step's keys once it has ended, the mock's without one."""
        if action in ("go", "record", "auto") and self.ended is not None:
            return True
        return action in ("go", "auto") and self._guided.mover is None

    def action_go(self) -> None:
        try:
            self.status(self._guided.move_to_pose(*self._target()))
        except (GuidedError, MotionError) as exc:
            self.status(str(exc), "red")

    def _target(self) -> tuple[np.ndarray, np.ndarray]:
        k = self.recorded
        return self.plan.meas.position[k], self.plan.meas.rotations.as_matrix()[k]

    def action_record(self) -> None:
        self.busy = True
        self.refresh_bindings()
        self._record_worker()

    @work(thread=True, exclusive=True, group="record")
    def _record_worker(self) -> None:
        self._record_one()
        self.hexcal.post(self._done_busy)

    def _record_one(self) -> str:
        """Record the next planned pose where the platform stands and diagnose again (in a
        worker): ``refused`` (record it again), ``compared``, or ``failed`` (recorded, the
        diagnosis failed: said in the status line)."""
        g = self._guided
        try:
            ok, msg = g.record_extra(PLAN_STEP)
        except GuidedError as exc:
            ok, msg = False, str(exc)
        self.hexcal.post(self.status, msg, "" if ok else "red")
        if not ok:
            return "refused"
        self.recorded += 1
        self.hexcal.post(self._working.start, "diagnosing again with the new pose")
        return "compared" if self._compare() else "failed"

    def _compare(self) -> bool:
        from hexcal.app.workflow import diagnose_chain
        from hexcal.diagnosis.decide import standing

        try:
            inp = self._inputs()
            (d,) = diagnose_chain(inp, self.hexcal.procedure.model, add=self.held)  # type: ignore[union-attr]
            st = standing(d, self.offer, self.rows[0][1].hypotheses)
        except (ValueError, np.linalg.LinAlgError) as exc:
            self.hexcal.post(self._working.stop)
            self.hexcal.post(self.status, f"cannot diagnose: {exc}", "red")
            return False
        self.hexcal.post(self._compared, self.recorded, st, str(d.verdict))
        return True

    def _compared(self, n: int, st: Any, verdict: str) -> None:
        self._working.stop()
        self.rows.append((n, st, verdict))
        if st.decided:
            self.ended = "decided"
        elif n >= len(self.plan.meas):
            self.ended = "spent"
        self._show()

    def _done_busy(self) -> None:
        self.busy = self.auto_running = False
        self._show()

    def action_auto(self) -> None:
        if self.busy:
            self._stop_auto = True
            self.status("stopping after this pose…", "yellow")
            return
        self._stop_auto = False
        self.busy = self.auto_running = True
        self.refresh_bindings()
        self._auto_worker()

    @work(thread=True, exclusive=True, group="record")
    def _auto_worker(self) -> None:
        """The mock operator: to each planned pose, record it (again where it stands when
        refused), until the question is decided or the plan is spent."""
        refused = 0
        while self.ended is None and not self._stop_auto and self.recorded < len(self.plan.meas):
            before = len(self.rows)
            try:
                if refused == 0:
                    self._guided.move_to_pose(*self._target())
            except (GuidedError, MotionError) as exc:
                self.hexcal.post(self.status, str(exc), "red")
                break
            done = self._record_one()
            if done == "failed":
                break
            if done == "compared":
                refused = 0
                self._wait_shown(before)
                continue
            refused += 1
            if refused > MAX_REFUSED:
                self.hexcal.post(self.status, "too many refused poses: stopping", "red")
                break
        self.hexcal.post(self._done_busy)

    def _wait_shown(self, before: int) -> None:
        """Until the app has shown the last diagnosis (``ended`` is set there)."""
        import time

        end = time.monotonic() + 30
        while len(self.rows) <= before and time.monotonic() < end:
            time.sleep(0.02)

    def action_back(self) -> None:
        self.app.pop_screen()


def _schedule_text(plan: Any, k: int) -> str:
    """Before the first planned pose of a plan with a schedule: how long to wait, and at what
    temperature to hold the rig (the plan's t and temperature columns)."""
    wait = float(getattr(plan, "wait", 0.0))
    if k > 0 or wait <= 0:
        return ""
    temp = plan.meas.temperature
    held = "" if temp is None else f", the rig held at {float(temp[0]):.2f} °C"
    return f"First wait {wait / 60:.0f} min after the session's last pose{held} (the plan's schedule). "
