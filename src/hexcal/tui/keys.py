"""The key bar at the foot of every screen, and how a key the state does not allow answers.

The bar lists the screen's keys, those the state allows first (bright), then those it does not
(dim): it wraps between keys, never inside one, so every key fits from 80 columns up. A key the
state does not allow is not silent: pressed, the screen says why in its status line (see
:meth:`hexcal.tui.app.HexcalScreen.why_not`).
"""

from __future__ import annotations

from typing import NamedTuple

from textual.content import Content
from textual.geometry import Size
from textual.screen import Screen
from textual.widget import Widget


class Key(NamedTuple):
    key: str  #: as bound ("ctrl+n")
    shown: str  #: as shown ("^n")
    description: str
    allowed: bool


class KeyBar(Widget):
    """The screen's keys (see module docstring); a click presses the key."""

    DEFAULT_CSS = """
    KeyBar {
        height: auto;
        background: $footer-background;
        color: $footer-foreground;
        padding: 0 1;
        link-style: none;
        link-style-hover: reverse;
        link-background-hover: $footer-background;
    }
    """

    def on_mount(self) -> None:
        self.screen.bindings_updated_signal.subscribe(self, self._bindings_changed)

    def on_unmount(self) -> None:
        self.screen.bindings_updated_signal.unsubscribe(self)

    def _bindings_changed(self, screen: Screen) -> None:
        self.refresh(layout=True)

    def keys(self) -> list[Key]:
        """The keys in the bar's order: allowed first."""
        out = []
        for ab in self.screen.active_bindings.values():
            b = ab.binding
            if b.show and b.description:
                out.append(Key(b.key, self.app.get_key_display(b), b.description, ab.enabled))
        return [k for k in out if k.allowed] + [k for k in out if not k.allowed]

    def _lines(self, width: int) -> list[list[Key]]:
        lines: list[list[Key]] = [[]]
        used = 0
        for key in self.keys():
            n = len(key.shown) + 1 + len(key.description) + 2  # "k desc" and two spaces
            if lines[-1] and used + n - 2 > width:
                lines.append([])
                used = 0
            lines[-1].append(key)
            used += n
        return lines

    def get_content_height(self, container: Size, viewport: Size, width: int) -> int:
        return len(self._lines(width))

    def render(self) -> Content:
        parts = []
        for line in self._lines(self.content_size.width or 80):
            parts.append(
                Content("  ").join(
                    Content.from_markup(
                        f"[@click=screen.press({k.key!r})]"
                        + (
                            "[b $footer-key-foreground]$key[/] $desc"
                            if k.allowed
                            else "[dim]$key $desc[/]"
                        )
                        + "[/]",
                        key=k.shown,
                        desc=k.description,
                    )
                    for k in line
                )
            )
        return Content("\n").join(parts)
