"""The key reference, over the live screen."""

from __future__ import annotations

from rich.table import Table
from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.keys import key_to_character
from textual.screen import ModalScreen
from textual.widgets import Static

ABOUT = (
    "Left: both devices (state, rate, drops, errors, clock, sync) and the recording.\n"
    "Middle: the leveled 100x100 image the CNN sees and the sagittal profile.\n"
    "Right: the fused decision, the CNN's probabilities, terrain features.\n"
    "Bottom: the last 20 s — true mode (yours), CNN decision, fused decision.\n"
    "A label key applies from the moment it is pressed until the next one."
)


def key_label(key: str) -> str:
    """How a Textual key name reads on a keyboard: question_mark -> ?, space -> space."""
    labels = []
    for k in key.split(","):
        k = k.strip()
        ch = key_to_character(k) if len(k) > 1 else k
        labels.append(k if ch is None or not ch.strip() else ch)
    return "/".join(labels)


class HelpScreen(ModalScreen[None]):
    DEFAULT_CSS = """
    HelpScreen { align: center middle; }
    HelpScreen > Vertical {
        width: 84; max-width: 95%; height: auto; max-height: 95%;
        border: round $accent; padding: 0 1; background: $surface;
    }
    """
    BINDINGS = [Binding("escape,q,question_mark", "close", "Close")]

    def __init__(self, keys: list[tuple[str, str]]) -> None:
        """`keys`: (key, what it does), in the order to show."""
        super().__init__()
        self.keys = keys

    def compose(self) -> ComposeResult:
        table = Table.grid(padding=(0, 2))
        table.add_column(style="bold", no_wrap=True)
        table.add_column()
        for key, what in self.keys:
            table.add_row(key_label(key), what)
        with Vertical():
            yield Static(Text("walkcap keys", style="bold"))
            yield Static(table, id="help-keys")
            yield Static(Text("\n" + ABOUT, style="dim"))
            yield Static(Text("\nescape closes", style="dim italic"))

    def action_close(self) -> None:
        self.dismiss(None)
