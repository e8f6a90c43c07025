"""What every screen of hexcal's text UI shares: :class:`HexcalScreen` (keys that say why they
cannot run, the status line) and its :class:`Foot`, and :class:`HexcalHost`, what the screens
use of the app. The screens import this module, never the app's: the app imports them."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, runtime_checkable

from textual import events
from textual.app import ComposeResult
from textual.containers import Vertical
from textual.content import Content
from textual.screen import Screen
from textual.widgets import RichLog, Static

from hexcal.procedure.guided import GuidedSession
from hexcal.procedure.steps import Procedure
from hexcal.tui.backend import Backend, Rig
from hexcal.tui.keys import KeyBar

if TYPE_CHECKING:
    from hexcal.procedure.recording import Step
    from hexcal.procedure.session import SessionFile


@runtime_checkable
class HexcalHost(Protocol):
    """What hexcal's screens use of the app they run in (:class:`hexcal.tui.app.HexcalApp`)."""

    backend: Backend
    rig: Rig | None
    guided: GuidedSession | None
    procedure: Procedure | None
    procedure_name: str
    session_path: Path
    sessions_dir: Path

    def post(self, fn: Callable[..., object], *args: object) -> None: ...
    def take_device_messages(self) -> list[tuple[str, int]]: ...
    def begin(self, sf: SessionFile, proc: Procedure) -> object: ...
    def steps(self, proc: Procedure) -> list[Step]: ...


class HexcalScreen(Screen):
    """A screen of hexcal's UI: ``hexcal`` is the app it runs in (:class:`HexcalHost`).

    Every key answers: a key the state does not allow is greyed out in the key bar
    (:class:`~hexcal.tui.keys.KeyBar`) and, pressed, says why in the screen's status line
    (:meth:`why_not`), whether or not the bar shows it (:meth:`hidden`)."""

    #: Narrow and short screens get the classes ``-narrow`` / ``-short``: the CSS tightens them.
    HORIZONTAL_BREAKPOINTS = [(0, "-narrow"), (100, "-wide")]
    VERTICAL_BREAKPOINTS = [(0, "-short"), (32, "-tall")]

    def why_not(self, action: str) -> str | None:
        """Why this screen's ``action`` cannot run now, one line for the operator (None: it
        can)."""
        return None

    def hidden(self, action: str) -> bool:
        """Whether the key bar leaves ``action`` out while it cannot run (pressed, it still
        says why)."""
        return False

    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        if self.why_not(action) is None:
            return True
        return False if self.hidden(action) else None

    def on_key(self, event: events.Key) -> None:
        """A key whose action cannot run says why instead of doing nothing; one that can
        clears the last reason."""
        for binding in self._bindings.key_to_bindings.get(event.key, ()):
            why = self.why_not(binding.action)
            if why is not None:
                event.stop()
                event.prevent_default()
                self.status(why, "yellow")
            else:
                self.status("")
            return

    def status(self, text: str, style: str = "") -> None:
        """One line for the operator in the status line, above the key bar."""
        self.query_one("#status", Static).update(Content.styled(text, style))

    def action_press(self, key: str) -> None:
        """A click on the key bar: as if the key were pressed."""
        self.app.simulate_key(key)

    @property
    def hexcal(self) -> HexcalHost:
        app = self.app
        if not isinstance(app, HexcalHost):
            raise TypeError(f"hexcal's screens run in a HexcalApp, not in a {type(app).__name__}")
        return app


class Foot(Vertical):
    """The foot of a screen, docked at the bottom: what is given (buttons...), then the status
    line (``#status``, see :meth:`HexcalScreen.status`), then the keys."""

    DEFAULT_CSS = "Foot { dock: bottom; height: auto; }"

    def compose(self) -> ComposeResult:
        yield Static("", id="status")
        yield KeyBar()


class WrappedLog(RichLog):
    """A log whose lines wrap at the width it shows, and wrap again when it is resized.

    RichLog wrapped a line once, at the width it had when written, the scroll bar's gutter
    counted in: the gutter then hid the last 2 characters of every wrapped line (a session
    file's name lost two), and a resized log kept its old wrapping. This one keeps what was
    written (the last :attr:`KEPT` lines) and renders it again at each new width."""

    KEPT = 1000

    def __init__(self, **kwargs: object) -> None:
        super().__init__(wrap=True, markup=True, **kwargs)  # type: ignore[arg-type]
        self._said: deque[str] = deque(maxlen=self.KEPT)
        self._wrapped_at = 0

    def say(self, markup: str) -> None:
        """Add one message (Rich markup) at the end."""
        self._said.append(markup)
        if self._wrapped_at:
            self.write(markup, width=self._wrapped_at)

    def on_resize(self, event: events.Resize) -> None:
        width = self.scrollable_content_region.width
        if width > 0 and width != self._wrapped_at:
            self._wrapped_at = width
            self.clear()
            for markup in self._said:
                self.write(markup, width=width)

    def text(self) -> str:
        """What it shows, a line per line (for tests and copies)."""
        return "\n".join(line.text for line in self.lines)
