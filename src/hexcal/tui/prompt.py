"""A one-line question to the operator: a note for the session file, a temperature."""

from __future__ import annotations

from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import Input, Label


class TextPrompt(ModalScreen[str | None]):
    """Ask ``question``; Enter returns the text typed, Escape returns None."""

    BINDINGS = [Binding("escape", "cancel", "Cancel")]

    def __init__(self, question: str, placeholder: str = "") -> None:
        super().__init__()
        self.question = question
        self.placeholder = placeholder

    def compose(self):
        with Vertical(id="prompt"):
            yield Label(self.question, id="prompt-question")
            yield Input(placeholder=self.placeholder, id="prompt-input")
            yield Label("Enter to keep it, Escape to cancel", id="prompt-help")

    def on_mount(self) -> None:
        self.query_one("#prompt-input", Input).focus()

    def on_input_submitted(self, event: Input.Submitted) -> None:
        self.dismiss(event.value)

    def action_cancel(self) -> None:
        self.dismiss(None)
