"""``hexcal run``: the operator's text UI.

Start → (new session: robot, devices, procedure, session file | resume a session file) → the
guided recording, step by step (:mod:`hexcal.tui.record`) → the Model 36/42 result and the
diagnosis, adding effects until the residual is at the noise floor (:mod:`hexcal.tui.results`)
→ export. Everything recorded is saved in the session file after every pose.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path

import numpy as np
from textual import on, work
from textual.app import App, ComposeResult
from textual.containers import Grid, Horizontal, VerticalScroll
from textual.message import Message
from textual.widgets import Button, DataTable, Header, Input, Label, Select, Static

from hexcal.io.advice import command
from hexcal.procedure.guided import GuidedSession
from hexcal.procedure.recording import Step
from hexcal.procedure.session import Session, SessionFile, SessionFileError
from hexcal.procedure.sessions_dir import (
    SessionEntry,
    list_sessions,
    new_session_path,
    sessions_dir,
)
from hexcal.procedure.steps import BUILTIN, Procedure, load_procedure
from hexcal.tui.backend import Backend, Rig
from hexcal.tui.record import RecordScreen
from hexcal.tui.screen import Foot, HexcalScreen
from hexcal.vocabulary import counted


class StartScreen(HexcalScreen):
    """Robot, devices, procedure and session file; start a new session or resume one."""

    BINDINGS = [
        ("ctrl+n", "new", "new session"),
        ("ctrl+r", "resume", "resume session"),
        ("ctrl+l", "sessions", "sessions"),
    ]

    def compose(self) -> ComposeResult:
        app = self.hexcal
        yield Header()
        # The buttons, the status line and the keys are docked at the foot: seen at any
        # height, the form above them scrolls.
        with Foot():
            with Horizontal(id="start-buttons"):
                yield Button("New session", id="new", variant="primary")
                yield Button("Resume session", id="resume")
        with VerticalScroll(id="start"):
            yield Static(
                "[b]hexcal[/b] — calibrate a Gough–Stewart platform by clamping its legs.\n"
                "Start a new session or resume one; every pose is saved in the session file "
                "as it is recorded.",
                id="intro",
            )
            with Grid(id="start-form"):
                yield Label("Robot (design)")
                yield Static(app.backend.design.name or "unnamed robot", id="robot")
                yield Label("Devices")
                yield Static(app.backend.label, id="devices")
                yield Label("Procedure")
                yield Select(
                    [(load_procedure(k).name, k) for k in BUILTIN],
                    value=app.procedure_name,
                    allow_blank=False,
                    id="procedure",
                )
                yield Label("Session file")
                yield Input(str(app.session_path), id="session-path")
            yield Static(f"Sessions in {app.sessions_dir}", id="sessions-title")
            yield DataTable(id="sessions", cursor_type="row", zebra_stripes=True)

    def on_mount(self) -> None:
        self.query_one("#new", Button).focus()  # Enter starts; Tab reaches the fields
        self.call_after_refresh(self._show_file_name)
        table = self.query_one("#sessions", DataTable)
        table.add_columns(*SessionEntry.COLUMNS)
        self.entries = list_sessions(self.hexcal.sessions_dir)
        for entry in self.entries:
            table.add_row(*entry.row(), key=str(entry.path))
        if self.entries:  # the list may be below the fold at 24 rows: its title says how to go
            self.query_one("#sessions-title", Static).update(
                f"{counted(len(self.entries), 'session')} in {self.hexcal.sessions_dir}: "
                "[b]ctrl+l[/b] to choose one ↓"
            )
        else:
            table.display = False
            self.query_one("#sessions-title", Static).update(
                f"Sessions are kept in {self.hexcal.sessions_dir} (none yet)"
            )

    def on_resize(self) -> None:
        self.call_after_refresh(self._show_file_name)

    def on_input_changed(self, event: Input.Changed) -> None:
        if event.input.id == "session-path":
            self._cue(event.input)

    def _show_file_name(self) -> None:
        """A path longer than its field shows its end, the file's name (it showed the folders
        and cut the name), and says that its start is hidden."""
        field = self.query_one("#session-path", Input)
        field.scroll_to(x=field.max_scroll_x, animate=False, immediate=True)
        self._cue(field)

    @staticmethod
    def _cue(field: Input) -> None:
        cut = len(field.value) > field.content_region.width
        field.border_subtitle = "… starts further left: Home" if cut else ""

    def why_not(self, action: str) -> str | None:
        if action == "sessions" and not getattr(self, "entries", None):
            return f"no session in {self.hexcal.sessions_dir} yet: start a new one (ctrl+n)"
        return None

    def action_sessions(self) -> None:
        """Move to the list of sessions: arrows choose, Enter resumes."""
        self.query_one("#sessions", DataTable).focus()
        self._say("choose a session with ↑ ↓ and press Enter to resume it")

    def on_data_table_row_selected(self, event: DataTable.RowSelected) -> None:
        self.query_one("#session-path", Input).value = str(event.row_key.value)
        self.action_resume()

    def on_button_pressed(self, event: Button.Pressed) -> None:
        if event.button.id == "new":
            self.action_new()
        else:
            self.action_resume()

    def _say(self, text: str, style: str = "") -> None:
        self.status(text, style)

    def action_new(self) -> None:
        app = self.hexcal
        path = Path(self.query_one("#session-path", Input).value.strip())
        name = str(self.query_one("#procedure", Select).value)
        try:
            proc = load_procedure(name)
            app.steps(proc)  # pose counts beyond what a session holds: refused before it exists
            path.parent.mkdir(parents=True, exist_ok=True)
            sf = SessionFile.create(
                path, Session(robot=app.backend.design, procedure=proc.model_dump(by_alias=True))
            )
        except (SessionFileError, ValueError, OSError) as exc:
            self._say(str(exc), "red")
            return
        self._say("opening the devices…")
        app.begin(sf, proc)

    def action_resume(self) -> None:
        app = self.hexcal
        path = Path(self.query_one("#session-path", Input).value.strip())
        try:
            sf = SessionFile.resume(path)
            if sf.session.procedure is None:
                raise SessionFileError(
                    f"{path}: holds no procedure (imported from a table?) — calibrate it with "
                    f"`{command('calibrate', path)}`, or start a new session"
                )
            proc = Procedure.model_validate(sf.session.procedure)
            app.steps(proc)  # the pose counts held to what a session holds
        except (SessionFileError, ValueError) as exc:
            self._say(str(exc), "red")
            return
        self._say(
            f"resuming {path} ({counted(sf.session.pose_count(), 'pose')})… opening the devices…"
        )
        # What loading did (poses set aside, a stale lock taken over, orphan temporary files
        # removed) was logged: the log handler brings it to the recording log, once (it is in
        # sf.notices too, for callers without a log handler).
        app.begin(sf, proc)


class RunInApp(Message):
    """A callable for the app's thread, posted from a worker or device thread."""

    def __init__(self, fn: Callable[..., object], args: tuple[object, ...]):
        super().__init__()
        self.fn, self.args = fn, args


class _ToScreen(logging.Handler):
    """hexcal's log records (driver warnings: a late tracker, a silent node...) shown in the UI
    instead of written over the screen. Emitting never waits for the UI: device threads log
    while the app may be busy closing them."""

    def __init__(self, app: HexcalApp):
        super().__init__(logging.INFO)
        self.app = app

    def emit(self, record: logging.LogRecord) -> None:
        self.app.post(self.app.device_message, record.getMessage(), record.levelno)


class HexcalApp(App):
    """The operator's UI. ``backend`` opens the devices; ``session_path`` is proposed on the
    start screen; ``poses_per_step`` / ``free_poses`` override the procedure's recommended
    counts (a quick tour, tests); ``sessions``: the sessions directory
    (:mod:`hexcal.procedure.sessions_dir`), listed on the start screen and where a new session
    goes unless ``session_path`` is given."""

    CSS_PATH = "hexcal.tcss"
    TITLE = "hexcal"

    def __init__(
        self,
        backend: Backend,
        session_path: str | Path | None = None,
        procedure: str = "model42-direction-length",
        poses_per_step: int | None = None,
        free_poses: int | None = None,
        sessions: str | Path | None = None,
    ):
        super().__init__()
        self.backend = backend
        self.sessions_dir = sessions_dir(sessions)
        self.session_path = (
            Path(session_path) if session_path else new_session_path(self.sessions_dir)
        )
        self.procedure_name = procedure
        self.poses_per_step = poses_per_step
        self.free_poses = free_poses
        self.rig: Rig | None = None
        self.guided: GuidedSession | None = None
        self.procedure: Procedure | None = None
        #: Device messages waiting for the recording log (the last 200).
        self.device_backlog: deque[tuple[str, int]] = deque(maxlen=200)
        self.sub_title = backend.title or backend.label

    def post(self, fn: Callable[..., object], *args: object) -> None:
        """Run ``fn(*args)`` on the app's thread, from any thread, without waiting for it
        (``call_from_thread`` waits, and would deadlock a worker against an app closing the
        devices that worker reads). Dropped once the app has stopped."""
        self.post_message(RunInApp(fn, args))

    @on(RunInApp)
    def _run_in_app(self, message: RunInApp) -> None:
        message.fn(*message.args)

    def on_mount(self) -> None:
        # Not ``_log``: that is Textual's own App._log, which every ``self.log`` call goes
        # through.
        self._hexcal_log = logging.getLogger("hexcal")
        self._handler = _ToScreen(self)
        self._hexcal_log.addHandler(self._handler)
        self._propagate, self._hexcal_log.propagate = self._hexcal_log.propagate, False
        self.push_screen(StartScreen())

    def device_message(self, text: str, level: int = logging.WARNING) -> None:
        """A message from the devices: into the recording log. Elsewhere it waits for the
        recording screen (never drawn over the results' charts); a warning says so in the
        screen's status line."""
        if isinstance(self.screen, RecordScreen):
            self.screen.log_line(text, "yellow" if level >= logging.WARNING else "")
            return
        self.device_backlog.append((text, level))
        if level >= logging.WARNING and isinstance(self.screen, HexcalScreen):
            short = text if len(text) <= 60 else text[:59] + "…"
            self.screen.status(f"device: {short} (in the recording log)", "yellow")

    def take_device_messages(self) -> list[tuple[str, int]]:
        """The device messages that came while the recording screen was not shown."""
        out = list(self.device_backlog)
        self.device_backlog.clear()
        return out

    def steps(self, proc: Procedure) -> list[Step]:
        from hexcal.app.workflow import procedure_steps

        return procedure_steps(proc, self.poses_per_step, self.free_poses)

    @work(thread=True, exclusive=True, group="devices")
    def begin(self, sf: SessionFile, proc: Procedure) -> None:
        """Open the devices (in a worker: it takes a second), then start recording."""
        try:
            rig = self.rig or self.backend.open()
        except Exception as exc:  # any driver error: show it, stay on the start screen
            sf.close()  # the session's lock: resuming it again must find it free
            self.post(self._start_failed, exc)
            return
        self.rig = rig
        if rig.devices is not None and sf.session.devices is None:
            sf.session.devices = rig.devices
            sf.save()
        design = sf.session.robot
        self.procedure = proc
        self.guided = GuidedSession(
            sf,
            self.steps(proc),
            rig.acquisition,
            platform_radius_mm=float(np.linalg.norm(design.b, axis=1).max()),
            mover=rig.mover,
            encoders=rig.encoders,
            clock_start=time.monotonic(),
            thermometer=rig.thermometer,
        )
        self.post(self._show_recording)

    def _start_failed(self, exc: Exception) -> None:
        screen = self.screen
        if isinstance(screen, StartScreen):
            screen._say(f"could not open the devices: {exc}", "red")

    def _show_recording(self) -> None:
        self.switch_screen(RecordScreen())

    def on_unmount(self) -> None:
        if self.guided is not None:
            self.guided.sf.close()  # the session's lock: another program may open it now
        self._hexcal_log.removeHandler(self._handler)
        self._hexcal_log.propagate = self._propagate
        self.backend.close()


def run_app(app: HexcalApp) -> int:
    app.run()
    return 0
