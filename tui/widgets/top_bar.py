"""The one-line status bar over the live screen (subject, trial, true mode, recording)."""

from __future__ import annotations

from rich.text import Text
from textual.widget import Widget


class TopBar(Widget):
    """Redrawn in place: its height never changes, so no relayout of the screen."""

    DEFAULT_CSS = """
    TopBar { height: 1; }
    """

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self._text = Text()

    def present(self, text: Text) -> None:
        if text != self._text:
            self._text = text
            self.refresh()

    def render(self) -> Text:
        return self._text
