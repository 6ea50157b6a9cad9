"""The key reference, over the live screen."""

from __future__ import annotations

from rich.table import Table
from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import VerticalScroll
from textual.keys import key_to_character
from textual.screen import ModalScreen
from textual.widgets import Static

ABOUT = (
    "Top: subject · condition · trial, the true mode in force; below it the banner (red while "
    "a trial records: elapsed time and the file; amber when the pre-flight check failed and "
    "recording is blocked) and the alarm line (red: act now, amber: worth knowing).\n"
    "devices — per device: state and backend; rate = measured of configured (fps, Hz); drops = "
    "frames or samples lost because walkcap fell behind; errors = device-side faults "
    "(bad checksums, missing packets, reconnects, frames the mock did not render); "
    "drift = how fast the IMU clock runs against the computer's, ppm; sync error p99 = how far "
    "an IMU sample's time is from when it was taken, 99th percentile, ms. pipeline: frames "
    "processed; latency = frame received to fused decision, median and p99, ms.\n"
    "recording — elapsed time, file, size, write rate, writer queue (how full; full loses "
    "data), gaps this trial (data the device counted and the file lacks; walkcap info counts "
    "the same), messages dropped.\n"
    "image — the leveled 100 x 100 image the CNN sees (1 cm cells, seen from the left, "
    "walking to the right). profile — the terrain's height along the walk.\n"
    "fused: <method> — the mode after fusion by that method; CNN probabilities — "
    "each mode's probability for the latest frame, 0.00-1.00; terrain geometry — what a fit of the "
    "profile finds (slope, riser, tread), not a decision.\n"
    "last 20 s — rows: true (your labels), CNN (the per-frame decision), fused (after the "
    "HMM), sim (mock devices: the simulator's truth).\n"
    "trials this session — trial, duration, size, labels, gaps, the file's full path.\n"
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
    HelpScreen > VerticalScroll {
        width: 100; max-width: 95%; height: auto; max-height: 95%;
        border: round $accent; padding: 0 1; background: $surface;
        border-subtitle-color: $text-muted;
    }
    """
    # a small terminal scrolls the help (the keys first); its frame says how to leave
    BINDINGS = [
        Binding("escape,q,question_mark", "close", "Close"),
        Binding("down,j", "scroll(1)", "scroll", show=False),
        Binding("up,k", "scroll(-1)", "scroll", show=False),
        Binding("pagedown", "scroll(10)", "scroll", show=False),
        Binding("pageup", "scroll(-10)", "scroll", show=False),
    ]

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
        with VerticalScroll() as box:
            box.border_subtitle = "escape closes · ↑↓ scroll"
            yield Static(Text("walkcap keys", style="bold"))
            yield Static(table, id="help-keys")
            yield Static(Text("\n" + ABOUT, style="dim"))
            yield Static(
                Text("\nescape closes; the mode keys label while this is open", style="dim italic")
            )

    def action_scroll(self, lines: int) -> None:
        box = self.query_one(VerticalScroll)
        box.scroll_to(y=box.scroll_y + lines, animate=False)

    def action_close(self) -> None:
        self.dismiss(None)
