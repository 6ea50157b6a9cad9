"""Ask for an optional note for a marker; enter places it, escape cancels."""

from __future__ import annotations

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import Input, Label


class MarkerDialog(ModalScreen[str | None]):
    """Dismisses with the note ("" for none) or None when cancelled."""

    DEFAULT_CSS = """
    MarkerDialog { align: center middle; }
    MarkerDialog > Vertical {
        width: 60; height: auto; border: round $accent; padding: 0 1; background: $surface;
    }
    MarkerDialog Input { margin: 1 0 0 0; }
    """
    BINDINGS = [Binding("escape", "cancel", "Cancel")]

    def compose(self) -> ComposeResult:
        with Vertical():
            yield Label("[b]Marker[/b]: an optional note, then enter (escape cancels)")
            yield Input(placeholder="e.g. subject stumbled", max_length=200, id="marker-note")

    def on_input_submitted(self, event: Input.Submitted) -> None:
        self.dismiss(event.value.strip())

    def action_cancel(self) -> None:
        self.dismiss(None)
