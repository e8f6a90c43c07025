"""The recording screen: one procedure step at a time.

The instruction; the live readings (pose, six leg lengths, tracker and bus status) refreshed
five times a second; the clamp monitor (is the clamped leg's length / direction really held?);
the pose count against the step's minimum and recommended counts; the predicted uncertainty of
the leg's points from the poses so far and the motion that would help most. Recording waits out
a still window, so it runs in a worker thread and the screen stays live.
"""

from __future__ import annotations

import logging
import textwrap

import numpy as np
from scipy.spatial.transform import Rotation
from textual import work
from textual.binding import Binding
from textual.containers import Horizontal, Vertical, VerticalScroll
from textual.content import Content
from textual.widgets import Header, ProgressBar, Static

from hexcal.estimate.nbp import Suggestion, motion_text
from hexcal.procedure.guided import GuidedError, GuidedSession, Live
from hexcal.procedure.recording import MOVED_ON, MotionError
from hexcal.tui.prompt import TextPrompt
from hexcal.tui.screen import Foot, HexcalScreen, WrappedLog
from hexcal.vocabulary import Constraint, counted

#: Width of a live number's column: eight characters and a space (``+219.735``).
COL = 9


def _num(x: float) -> str:
    """``x`` in eight characters, three decimals when they fit, fewer when not."""
    if not np.isfinite(x):
        return "     nan"
    for digits in (3, 2, 1, 0):
        text = f"{x:+8.{digits}f}"
        if len(text) <= 8:
            return text
    return "   ±huge"


def _row(label: str, values: np.ndarray | None, label_width: int) -> str:
    """A label and numbers in fixed columns (the row never wraps: see :func:`live_text`)."""
    nums = "—" if values is None else " ".join(_num(float(x)) for x in values)
    return f"{label:<{label_width}} {nums}"


def _status(text: str, width: int) -> list[str]:
    """A status line at ``width`` columns: wrapped at spaces under its label, never cut."""
    label = text.split("  ")[0] + "  " if "  " in text else ""
    return textwrap.wrap(
        text,
        max(width, 20),
        subsequent_indent=" " * min(len(label), 4),
        break_long_words=False,
        break_on_hyphens=False,
    ) or [""]


def leader_text(g: GuidedSession) -> str:
    """The live ranking's leader over the session's poses so far, as one line (empty before
    any pose): which candidate effect leads, and its ΔBIC margin over the next."""
    if not len(g.ranking):
        return ""
    leader, margin = g.ranking.leader()
    if leader is None:
        return "\nlive ranking: no candidate effect stands out yet"
    return (
        f"\nlive ranking: [b]{leader.effect}[/b] leads (ΔBIC {leader.delta_bic:.0f}, "
        f"{margin:.0f} ahead of the next) — diagnose at the end to name it"
    )


def live_text(lv: Live, structure: str, width: int) -> str:
    """The live panel at ``width`` columns: every row of numbers in fixed columns that fit —
    long labels from 40 columns, short ones below; the status lines wrapped, never cut."""
    wide = width >= 13 + 1 + 3 * COL - 1
    labels = (
        ("position mm", "rotation deg", "legs 1-3 mm", "legs 4-6 mm")
        if wide
        else ("pos mm", "rot deg", "legs1-3", "legs4-6")
    )
    lw = 12 if wide else 7
    return "\n".join(
        [
            *_status(f"tracker  {lv.tracker_status}", width),
            _row(labels[0], lv.position, lw),
            _row(labels[1], lv.rotvec_deg, lw),
            *_status(f"legs  {lv.bus_status}", width),
            _row(labels[2], lv.readings[:3], lw),
            _row(labels[3], lv.readings[3:], lw),
            *_status(structure, width),
        ]
    )


#: The action that lifts a refusal (:class:`hexcal.procedure.guided.Refusal`), as its key.
REMEDY_KEYS = {"clamp": "c", "record": "r", "calibrate": "k"}


class RecordScreen(HexcalScreen):
    """Guided recording (see module docstring)."""

    BINDINGS = [
        Binding("c", "clamp", "clamped"),
        Binding("m", "move", "move"),
        Binding("g", "go_suggested", "go there"),
        Binding("r", "record", "record"),
        Binding("u", "undo", "undo"),
        Binding("n", "finish", "next step"),
        Binding("s", "skip", "skip"),
        Binding("a", "auto", "auto"),
        Binding("A", "auto_all", "auto all"),
        Binding("o", "note", "note"),
        Binding("t", "temperature", "temp °C"),
        Binding("k", "calibrate", "calibrate"),
        Binding("q", "app.quit", "quit"),
    ]

    def __init__(self) -> None:
        super().__init__()
        self.busy = False
        self.auto_running = False
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
        yield Foot()
        with Horizontal(id="top"):
            # The count and the next best pose first: the instruction below them scrolls.
            with VerticalScroll(id="step-panel"):
                yield Static("", id="step-title")
                yield Static("", id="counts")
                yield ProgressBar(total=1, show_eta=False, show_percentage=False, id="progress")
                yield Static("", id="conditioning")
                yield Static("", id="instruction")
            with Vertical(id="live-panel"):
                yield Static("", id="live")
                yield Static("", id="clamp")
        with Horizontal(id="bottom"):
            yield WrappedLog(id="log", min_width=20)
            with VerticalScroll(id="steps-box"):
                yield Static("", id="steps")

    def on_mount(self) -> None:
        g = self.guided
        for box, title in (("#live-panel", "Live"), ("#log", "Log"), ("#steps-box", "Steps")):
            self.query_one(box).border_title = title
        self.query_one("#log", WrappedLog).say(
            f"session file [b]{g.sf.path}[/b]: {counted(g.sf.session.pose_count(), 'pose')} so far"
        )
        self.show_step()
        self.refresh_live()
        self.set_interval(0.2, self.refresh_live)
        self.on_screen_resume()

    def on_screen_resume(self) -> None:
        """Back on the recording screen: the device messages that came meanwhile."""
        for text, level in self.hexcal.take_device_messages():
            self.log_line(text, "yellow" if level >= logging.WARNING else "")

    def on_resize(self) -> None:
        self.call_after_refresh(self._fit)

    def _fit(self) -> None:
        """What depends on the panels' widths: the live columns, the steps' names."""
        self.refresh_live()
        self._show_steps()

    # -- display --------------------------------------------------------------------------------
    def log_line(self, text: str, style: str = "") -> None:
        self.query_one("#log", WrappedLog).say(f"[{style}]{text}[/{style}]" if style else text)

    def show_step(self) -> None:
        g = self.guided
        self.query_one("#progress").display = not g.finished
        if g.finished:
            self.query_one("#step-title", Static).update(
                "[b]Procedure complete[/b] — every step is done or skipped"
            )
            self.query_one("#step-panel").border_title = "Procedure complete"
            self.query_one("#instruction", Static).update(
                "Press [b]k[/b] to calibrate and see where the model fails."
            )
            self.query_one("#counts", Static).update(
                f"{counted(g.sf.session.pose_count(), 'pose')} recorded"
            )
            self.query_one("#conditioning", Static).update("")
        else:
            st = g.step
            what = f"leg {st.leg}, {st.constraint} clamped" if st.leg else st.name
            self.query_one("#step-title", Static).update(f"[b]{what}[/b]")
            self.query_one("#step-panel").border_title = f"Step {g.index + 1} of {len(g.steps)}"
            keys = (
                "[b]c[/b] when clamped, then move the platform and press [b]r[/b] at each pose"
                if st.leg
                else "move the platform and press [b]r[/b] at each pose"
            )
            if g.mover is not None:
                keys += " ([b]m[/b] moves the mock platform, [b]a[/b] does the whole step)"
            self.query_one("#instruction", Static).update(f"{keys}\n\n{st.instruction}")
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
            f"poses [b]{n}[/b] of {st.n_poses} recommended, minimum {st.min_poses}: {state}"
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
        self.query_one("#conditioning", Static).update(text + leader_text(g))

    def _show_steps(self) -> None:
        """One line per step, cut to the box (short names when narrow); the current step kept
        in view."""
        mark = {"done": "[green]✓[/green]", "skipped": "[yellow]–[/yellow]", "now": "[b]▶[/b]"}
        box = self.query_one("#steps", Static)
        width = box.size.width or 30
        rows = self.guided.summary()
        counts = [f"{n:>2}/{rec}" for _, _, n, _, rec in rows]
        room = max(6, width - 3 - max(len(c) for c in counts))
        lines, now = [], 0
        for i, ((name, state, *_), count) in enumerate(zip(rows, counts, strict=True)):
            if len(name) > room:
                name = name.replace("direction", "dir").replace("length", "len")
            if len(name) > room:
                name = name[: room - 1] + "…"
            lines.append(f"{mark.get(state, ' ')} {name:<{room}} {count}")
            now = i if state == "now" or self.guided.finished else now
        box.update("\n".join(lines))
        scroll = self.query_one("#steps-box", VerticalScroll)
        scroll.scroll_to(y=max(0, now - scroll.size.height // 2), animate=False)

    def refresh_live(self) -> None:
        g = self.guided
        lv = g.live()
        temp = g.temperature()
        structure = (
            "structure  temperature unknown (t)"
            if temp is None
            else f"structure  {temp:.1f} °C ({'thermometer' if g.thermometer else 'entered'})"
        )
        live = self.query_one("#live", Static)
        live.update(Content(live_text(lv, structure, live.size.width or 40)))
        style = "green" if lv.clamp_ok else "bold red"
        self.query_one("#clamp", Static).update(
            f"[b]clamp[/b] [{style}]{lv.clamp or 'nothing clamped in this step'}[/{style}]"
        )

    # -- actions --------------------------------------------------------------------------------
    #: The screen's actions as the guided session names them (its refusals say why not).
    ENGINE_ACTIONS = {
        "clamp": "clamp",
        "move": "move",
        "record": "record",
        "undo": "undo",
        "finish": "finish",
        "skip": "skip",
        "temperature": "temperature",
    }

    def why_not(self, action: str) -> str | None:
        g = self.guided
        if action in ("auto", "auto_all"):
            if g.mover is None:
                return "no motion controller: the mock operator needs one — record by hand"
            if g.finished:
                return self._refusal("skip")
            if self.busy and not self.auto_running:
                return "recording a pose: wait for it"
            return None  # while it runs, a stops it
        if action == "calibrate":
            return (
                None
                if g.sf.session.pose_count()
                else "nothing recorded yet: record a pose first (r)"
            )
        if self.busy and action != "note":
            # A note saves the file, as the recording worker does, but only once it is typed.
            if action in self.ENGINE_ACTIONS or action == "go_suggested":
                return (
                    "the mock operator is at work: a stops it"
                    if self.auto_running
                    else "recording a pose: wait for it"
                )
            return None
        if action == "go_suggested":
            return self._refusal("move") or self._refusal("suggest") or self._no_suggestion()
        if action in self.ENGINE_ACTIONS:
            return self._refusal(self.ENGINE_ACTIONS[action])
        return None

    def hidden(self, action: str) -> bool:
        """Out of the key bar: what this rig or this state never allows (pressed, it says
        why) — the mock's keys without a mock, the temperature with a thermometer, the step's
        keys once every step is done, clamping and the next best pose on a free step."""
        g = self.guided
        if action in ("move", "go_suggested", "auto", "auto_all"):
            if g.mover is None or g.finished:
                return True
        if action == "temperature":
            return g.thermometer is not None
        if g.finished:
            return action in ("clamp", "record", "undo", "finish", "skip")
        return action in ("clamp", "go_suggested") and not g.step.leg

    def _refusal(self, action: str) -> str | None:
        why = self.guided.refusal(action)
        if why is None:
            return None
        key = REMEDY_KEYS.get(why.remedy or "")
        return f"{why.text} ({key})" if key else why.text

    def _no_suggestion(self) -> str | None:
        if self.suggested is not None:
            return None
        return "no next best pose for these poses (a degenerate fit): move (m) and record (r)"

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
        if (msg := self._guard(self.guided.move)) is not None:
            self.log_line(msg)
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
        check = self._guard(self.guided.finish_step, self.hexcal.backend.design)
        if check is not None:
            self.log_line(check.message, "green" if check.ok else "red")
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
        self.auto_running = True
        g = self.guided
        self.log_line(
            "the mock operator records "
            + ("every step left" if all_steps else f"{g.step.name}")
            + ": a stops it"
        )
        self._set_busy(True)
        self._auto_worker(all_steps)

    def _auto_move(self, g: GuidedSession) -> None:
        """The mock operator follows the next best pose once there is one, else moves at random
        (re-clamping at home where a fresh clamp allows no pose: :meth:`GuidedSession.move`)."""
        s = g.suggestion(self.hexcal.backend.design) if g.clamped else None
        if s is not None:
            try:
                g.move_to_suggestion(s)
                return
            except MotionError:
                pass
        if (said := g.move()) != MOVED_ON:  # a re-clamp at home, worth the operator's eye
            self.hexcal.post(self.log_line, said, "yellow")

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
                check = g.finish_step(self.hexcal.backend.design)
                call(self.log_line, check.message, "green" if check.ok else "red")
                call(self.show_step)
                if check.ok and not all_steps:
                    break
        except (GuidedError, MotionError) as exc:
            call(self.log_line, str(exc), "red")
        call(self._auto_done)

    def _auto_done(self) -> None:
        self.auto_running = False
        self._set_busy(False)
        self.show_step()

    def action_calibrate(self) -> None:
        from hexcal.tui.results import ResultScreen

        self.app.push_screen(ResultScreen())
