"""Ask for an optional note for a marker; enter places it, escape cancels."""

from __future__ import annotations

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import Input, Label


class NoteInput(Input):
    """The note; the mode keys are not its to type: they label the trial meanwhile."""

    def __init__(self, mode_keys: frozenset[str] = frozenset(), **kwargs) -> None:
        super().__init__(**kwargs)
        self.mode_keys = mode_keys

    def check_consume_key(self, key: str, character: str | None) -> bool:
        return key not in self.mode_keys and super().check_consume_key(key, character)


class MarkerDialog(ModalScreen[str | None]):
    """Dismisses with the note ("" for none) or None when cancelled.

    `mode_keys` (Textual key names) label the trial while the note is typed, so they
    never type into it; the dialog says so."""

    DEFAULT_CSS = """
    MarkerDialog { align: center middle; }
    MarkerDialog > Vertical {
        width: 60; height: auto; border: round $accent; padding: 0 1; background: $surface;
    }
    MarkerDialog Input { margin: 1 0 0 0; }
    """
    BINDINGS = [Binding("escape", "cancel", "Cancel")]

    def __init__(self, mode_keys: frozenset[str] = frozenset(), keys_text: str = "") -> None:
        super().__init__()
        self.mode_keys = mode_keys
        self.keys_text = keys_text

    def compose(self) -> ComposeResult:
        with Vertical():
            yield Label("[b]Marker[/b]: an optional note, then enter (escape cancels)")
            if self.keys_text:
                yield Label(f"{self.keys_text} still label the trial: they do not type here")
            yield NoteInput(
                self.mode_keys,
                placeholder="e.g. subject stumbled",
                max_length=200,
                id="marker-note",
            )

    def on_input_submitted(self, event: Input.Submitted) -> None:
        self.dismiss(event.value.strip())

    def action_cancel(self) -> None:
        self.dismiss(None)
