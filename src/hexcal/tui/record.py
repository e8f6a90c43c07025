"""The recording screen: one procedure step at a time.

The instruction; the live readings (pose, six leg lengths, tracker and bus status) refreshed
five times a second; the clamp monitor (is the clamped leg's length / direction really held?);
the pose count against the step's minimum and recommended counts; the predicted uncertainty of
the leg's points from the poses so far and the motion that would help most. Recording waits out
a still window, so it runs in a worker thread and the screen stays live.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation
from textual import work
from textual.binding import Binding
from textual.containers import Horizontal, Vertical, VerticalScroll
from textual.widgets import Footer, Header, ProgressBar, RichLog, Static

from hexcal.estimate.nbp import Suggestion, motion_text
from hexcal.procedure.guided import GuidedError, GuidedSession
from hexcal.procedure.recording import MotionError
from hexcal.tui.app import HexcalScreen
from hexcal.tui.prompt import TextPrompt
from hexcal.vocabulary import Constraint


def _fmt(v: np.ndarray | None, digits: int = 3) -> str:
    if v is None:
        return "—"
    return "  ".join(f"{x:+9.{digits}f}" if np.isfinite(x) else "      nan" for x in v)


class RecordScreen(HexcalScreen):
    """Guided recording (see module docstring)."""

    BINDINGS = [
        Binding("c", "clamp", "Clamped"),
        Binding("m", "move", "Move"),
        Binding("g", "go_suggested", "Go suggested"),
        Binding("r", "record", "Record"),
        Binding("u", "undo", "Undo"),
        Binding("n", "finish", "Next step"),
        Binding("s", "skip", "Skip"),
        Binding("a", "auto", "Auto"),
        Binding("A", "auto_all", "Auto all", show=False),
        Binding("o", "note", "Note"),
        Binding("t", "temperature", "Temp °C"),
        Binding("k", "calibrate", "Calibrate"),
        Binding("q", "app.quit", "Quit"),
    ]

    def __init__(self) -> None:
        super().__init__()
        self.busy = False
        self._stop_auto = False
        self.suggested: Suggestion | None = None

    @property
    def guided(self) -> GuidedSession:
        guided = self.hexcal.guided
        if guided is None:
            raise RuntimeError("the recording screen needs a guided session: none is open")
        return guided

    def compose(self):
        yield Header()
        with Horizontal(id="top"):
            with Vertical(id="step-panel"):
                yield Static("", id="step-title")
                yield Static("", id="instruction")
                yield Static("", id="counts")
                yield ProgressBar(total=1, show_eta=False, show_percentage=False, id="progress")
                yield Static("", id="conditioning")
            with Vertical(id="live-panel"):
                yield Static("", id="live")
                yield Static("", id="clamp")
        with Horizontal(id="bottom"):
            yield RichLog(id="log", wrap=True, markup=True)
            with VerticalScroll(id="steps-box"):
                yield Static("", id="steps")
        yield Footer()

    def on_mount(self) -> None:
        g = self.guided
        self.query_one("#log", RichLog).write(
            f"session file [b]{g.sf.path}[/b]: {len(g.sf.session.poses)} poses so far"
        )
        self.show_step()
        self.refresh_live()
        self.set_interval(0.2, self.refresh_live)

    # -- display --------------------------------------------------------------------------------
    def log_line(self, text: str, style: str = "") -> None:
        self.query_one("#log", RichLog).write(f"[{style}]{text}[/{style}]" if style else text)

    def show_step(self) -> None:
        g = self.guided
        if g.finished:
            self.query_one("#step-title", Static).update(
                "[b]Procedure complete[/b] — every step is done or skipped"
            )
            self.query_one("#instruction", Static).update(
                "Press [b]k[/b] to calibrate and see where the model fails."
            )
            self.query_one("#counts", Static).update(f"{len(g.sf.session.poses)} poses recorded")
            self.query_one("#conditioning", Static).update("")
        else:
            st = g.step
            what = f"leg {st.leg}, {st.constraint} clamped" if st.leg else st.name
            self.query_one("#step-title", Static).update(
                f"[b]Step {g.index + 1} of {len(g.steps)}[/b] — {what}"
            )
            keys = (
                "[b]c[/b] when clamped, then move the platform and press [b]r[/b] at each pose"
                if st.leg
                else "move the platform and press [b]r[/b] at each pose"
            )
            if g.mover is not None:
                keys += " ([b]m[/b] moves the mock platform, [b]a[/b] does the whole step)"
            self.query_one("#instruction", Static).update(f"{st.instruction}\n\n{keys}")
            self._show_counts()
        self._show_steps()
        self.refresh_bindings()

    def _show_counts(self) -> None:
        g = self.guided
        st = g.step
        n = g.n_poses
        state = (
            "[green]enough — n for the next step[/green]"
            if n >= st.n_poses
            else "[yellow]minimum reached[/yellow]"
            if n >= st.min_poses
            else "[red]below the minimum[/red]"
        )
        self.query_one("#counts", Static).update(
            f"poses [b]{n}[/b]   minimum {st.min_poses}   recommended {st.n_poses}   {state}"
        )
        self.query_one("#progress", ProgressBar).update(
            total=st.n_poses, progress=min(n, st.n_poses)
        )
        design = self.hexcal.backend.design
        c = g.conditioning(design.b)
        self.suggested = g.suggestion(design) if g.clamped else None
        text = ""
        if st.leg and np.isfinite(c.sigma_a_mm):
            b = "" if np.isnan(c.sigma_b_mm) else f"platform point ±{c.sigma_b_mm:.3f} mm   "
            a = "clamped point" if st.constraint == Constraint.DIRECTION_LENGTH else "base point"
            text = f"predicted 1σ: {b}{a} ±{c.sigma_a_mm:.3f} mm   (condition {c.condition:.0f})\n"
        s = self.suggested
        if s is not None and s.done and n >= st.min_poses:
            text += (
                f"[green]target reached[/green]: predicted 1σ {s.sigma_before_mm:.3f} mm ≤ "
                f"{st.target_sigma_mm:g} mm — enough poses for this step, [b]n[/b] for the next"
            )
        elif s is not None and g.recorder is not None and g.recorder.poses:
            last = g.recorder.poses[-1]
            R_last = Rotation.from_quat(last.quaternion, scalar_first=True).as_matrix()
            why = (
                "to cover the workspace"
                if s.space_filling
                else f"1σ {s.sigma_before_mm:.3f} → {s.sigma_after_mm:.3f} mm"
            )
            move = motion_text(last.position, R_last, s.position, s.rotation)
            text += f"next best pose: {move} ({why})"
            if g.mover is not None:
                text += " — [b]g[/b] goes there"
        else:
            text += f"most useful motion: {c.hint}"
        self.query_one("#conditioning", Static).update(text)

    def _show_steps(self) -> None:
        mark = {"done": "[green]✓[/green]", "skipped": "[yellow]–[/yellow]", "now": "[b]▶[/b]"}
        lines = [
            f"{mark.get(state, ' ')} {name:<22} {n:>2}/{rec}"
            for name, state, n, _, rec in self.guided.summary()
        ]
        self.query_one("#steps", Static).update("\n".join(lines))

    def refresh_live(self) -> None:
        g = self.guided
        lv = g.live()
        temp = g.temperature()
        structure = (
            "structure  temperature unknown ([b]t[/b] to enter it)"
            if temp is None
            else f"structure  {temp:.1f} °C ({'thermometer' if g.thermometer else 'entered'})"
        )
        self.query_one("#live", Static).update(
            "[b]Live[/b]\n"
            f"tracker  {lv.tracker_status}\n"
            f"  position mm  {_fmt(lv.position)}\n"
            f"  rotation deg {_fmt(lv.rotvec_deg)}\n"
            f"legs mm  {lv.bus_status}\n"
            f"  1-3 {_fmt(lv.readings[:3])}\n"
            f"  4-6 {_fmt(lv.readings[3:])}\n"
            f"{structure}"
        )
        style = "green" if lv.clamp_ok else "bold red"
        self.query_one("#clamp", Static).update(
            f"[b]Clamp[/b]\n[{style}]{lv.clamp or 'nothing clamped in this step'}[/{style}]"
        )

    # -- actions --------------------------------------------------------------------------------
    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        g = self.guided
        if action in ("auto", "auto_all"):
            return g.mover is not None and not g.finished
        if self.busy and action not in ("calibrate",):
            # A note or a temperature saves the file, as the recording worker does: not at once.
            busy_off = ("clamp", "move", "record", "undo", "finish", "skip", "note", "temperature")
            return None if action in busy_off else True
        if action == "note":
            return True
        if action == "temperature":
            return g.thermometer is None or None
        if g.finished:
            return action in ("calibrate", "app.quit") or None
        st = g.step
        if action == "clamp":
            return (st.leg > 0 and not g.clamped) or None
        if action == "move":
            return (g.mover is not None and (st.leg == 0 or g.clamped)) or None
        if action == "record":
            return (st.leg == 0 or g.clamped) or None
        if action == "undo":
            return g.n_poses > 0 or None
        if action == "finish":
            return g.can_finish or None
        return True

    def _guard(self, fn, *args):
        try:
            return fn(*args)
        except (GuidedError, MotionError) as exc:
            self.log_line(str(exc), "red")
            return None

    def action_note(self) -> None:
        def keep(text: str | None) -> None:
            if text is not None and (msg := self._guard(self.guided.note, text)) is not None:
                self.log_line(msg)

        self.app.push_screen(
            TextPrompt("Note for the session file (kept with the time):", "e.g. re-clamped leg 3"),
            keep,
        )

    def action_temperature(self) -> None:
        def keep(text: str | None) -> None:
            if text is not None and (msg := self._guard(self.guided.set_temperature, text)):
                self.log_line(msg)
                self.show_step()

        self.app.push_screen(
            TextPrompt("Structure temperature now, °C (every next pose carries it):", "e.g. 21.5"),
            keep,
        )

    def action_clamp(self) -> None:
        if (msg := self._guard(self.guided.clamp)) is not None:
            self.log_line(msg)
        self.show_step()

    def action_move(self) -> None:
        self._guard(self.guided.move)
        self.refresh_live()

    def action_go_suggested(self) -> None:
        if self.suggested is not None:
            if (msg := self._guard(self.guided.move_to_suggestion, self.suggested)) is not None:
                self.log_line(msg)
        self.refresh_live()

    def action_undo(self) -> None:
        if (msg := self._guard(self.guided.undo)) is not None:
            self.log_line(msg, "yellow")
        self.show_step()

    def action_finish(self) -> None:
        check = self._guard(self.guided.finish_step)
        if check is not None:
            self.log_line(check.message, "red") if not check.ok else self.log_line(
                "step done", "green"
            )
        self.show_step()

    def action_skip(self) -> None:
        if (msg := self._guard(self.guided.skip_step)) is not None:
            self.log_line(msg, "yellow")
        self.show_step()

    def action_record(self) -> None:
        self._set_busy(True)
        self._record_worker()

    def _set_busy(self, busy: bool) -> None:
        self.busy = busy
        self.refresh_bindings()

    @work(thread=True, exclusive=True, group="record")
    def _record_worker(self) -> None:
        try:
            ok, msg = self.guided.record()
        except GuidedError as exc:
            ok, msg = False, str(exc)
        self.hexcal.post(self._recorded, ok, msg)

    def _recorded(self, ok: bool, msg: str) -> None:
        self.log_line(msg, "" if ok else "red")
        self._set_busy(False)
        self.show_step()

    def action_auto(self) -> None:
        self._auto(all_steps=False)

    def action_auto_all(self) -> None:
        self._auto(all_steps=True)

    def _auto(self, all_steps: bool) -> None:
        if self.busy:
            self._stop_auto = True
            self.log_line("stopping after this pose…", "yellow")
            return
        self._stop_auto = False
        self._set_busy(True)
        self._auto_worker(all_steps)

    def _auto_move(self, g: GuidedSession) -> None:
        """The mock operator follows the next best pose once there is one, else moves at random."""
        s = g.suggestion(self.hexcal.backend.design) if g.clamped else None
        if s is not None:
            try:
                g.move_to_suggestion(s)
                return
            except MotionError:
                pass
        g.move()

    @work(thread=True, exclusive=True, group="record")
    def _auto_worker(self, all_steps: bool) -> None:
        """The mock operator: clamp, move and record until the step's recommended count, then
        end the step (and go on through the procedure with ``all_steps``)."""
        g = self.guided
        call = self.hexcal.post
        refused = 0
        try:
            while not g.finished and not self._stop_auto:
                st = g.step
                if st.leg and not g.clamped:
                    call(self.log_line, g.clamp())
                if g.n_poses < st.n_poses and not g.target_met(self.hexcal.backend.design):
                    # A refused pose is recorded again where it stands, as record_procedure
                    # does: moving on would hide a motion from history-dependent effects.
                    if refused == 0:
                        self._auto_move(g)
                    ok, msg = g.record()
                    refused = 0 if ok else refused + 1
                    call(self.log_line, msg, "" if ok else "red")
                    call(self.show_step)
                    if refused > 5:
                        call(self.log_line, "too many refused poses: stopping", "red")
                        break
                    continue
                check = g.finish_step()
                call(
                    self.log_line,
                    check.message or f"{st.name} done",
                    "green" if check.ok else "red",
                )
                call(self.show_step)
                if check.ok and not all_steps:
                    break
        except (GuidedError, MotionError) as exc:
            call(self.log_line, str(exc), "red")
        call(self._set_busy, False)
        call(self.show_step)

    def action_calibrate(self) -> None:
        from hexcal.tui.results import ResultScreen

        if len(self.guided.sf.session.poses) < 1:
            self.log_line("nothing recorded yet", "red")
            return
        self.app.push_screen(ResultScreen())
