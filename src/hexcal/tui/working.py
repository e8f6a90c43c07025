"""A computation under way on a screen (a calibration, a diagnosis, a refit): Textual's
progress bar, running without an end (these jobs do not know their length), what is being
done and for how long. Shown while the screen's worker runs, gone when its result is shown."""

from __future__ import annotations

import time

from textual.app import ComposeResult
from textual.containers import Horizontal
from textual.timer import Timer
from textual.widgets import ProgressBar, Static


class Working(Horizontal):
    """``start(text)`` when the worker starts, ``stage(text)`` as it goes on, ``stop()`` when
    its result is shown."""

    DEFAULT_CSS = """
    Working { height: 1; display: none; padding: 0 1; }
    Working ProgressBar { width: 22; }
    Working #working-text { width: 1fr; height: 1; }
    """

    def __init__(self, **kwargs: object) -> None:
        super().__init__(**kwargs)  # type: ignore[arg-type]
        self._t0 = 0.0
        self._text = ""
        self._timer: Timer | None = None

    def compose(self) -> ComposeResult:
        yield ProgressBar(total=None, show_percentage=False, show_eta=False)
        yield Static("", id="working-text")

    @property
    def text(self) -> str:
        """What is being done (without the time)."""
        return self._text

    def start(self, text: str) -> None:
        self._t0 = time.monotonic()
        self.display = True
        self.stage(text)
        if self._timer is None:
            self._timer = self.set_interval(0.5, self._tick)
        else:
            self._timer.resume()

    def stage(self, text: str) -> None:
        self._text = text
        self._tick()

    def stop(self) -> None:
        self.display = False
        if self._timer is not None:
            self._timer.pause()

    def _tick(self) -> None:
        elapsed = time.monotonic() - self._t0
        # The time first: on a narrow terminal the end of the text is what is cut.
        self.query_one("#working-text", Static).update(f"{elapsed:3.0f} s  {self._text}…")


__all__ = ["Working"]
