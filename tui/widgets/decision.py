"""The fused decision, large, with the CNN's own decision and the operator's label under it,
then how often the decision switched in the last minute (and, on mock devices, the walker's
locomotion mode: what to key)."""

from __future__ import annotations

from rich.console import Group
from rich.text import Text
from textual.widget import Widget

from devices.frames import MODE_NAMES
from tui.widgets.modes import MODE_COLORS, mode_name, mode_text

# 5 x 5 pixel glyphs for the letters of the mode codes; each pixel is drawn two cells wide.
GLYPHS = {
    "L": ["#....", "#....", "#....", "#....", "#####"],
    "G": [".####", "#....", "#..##", "#...#", ".####"],
    "U": ["#...#", "#...#", "#...#", "#...#", ".###."],
    "S": [".####", "#....", ".###.", "....#", "####."],
    "D": ["####.", "#...#", "#...#", "#...#", "####."],
    "R": ["####.", "#...#", "####.", "#..#.", "#...#"],
    "-": [".....", ".....", "#####", ".....", "....."],
}


def big_letters(word: str) -> list[str]:
    """Five lines of block letters, two cells per pixel, two cells between letters."""
    rows = []
    for r in range(5):
        parts = [
            GLYPHS.get(ch, GLYPHS["-"])[r].replace("#", "██").replace(".", "  ") for ch in word
        ]
        rows.append("  ".join(parts))
    return rows


class DecisionDisplay(Widget):
    DEFAULT_CSS = """
    DecisionDisplay { height: 8; }
    """

    def on_resize(self) -> None:
        self.refresh()  # block letters or a band: it depends on the rows it has

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self._content: tuple = (None, None, None, False)

    def present(
        self,
        fused: int | str | None,
        cnn: int | str | None,
        label: str | None,
        unknown: bool = False,
    ) -> None:
        """`unknown`: the newest frame has no decision (a stale IMU orientation): the
        fusion holds, and the panel says so instead of showing an old decision as current."""
        content = (None if unknown else mode_name(fused), mode_name(cnn), mode_name(label), unknown)
        if content != self._content:
            self._content = content
            self.refresh()

    def render(self) -> Group:
        """Block letters when the widget has the rows for them, else a band of the mode's
        colour with its letters: the decision reads at a glance at any height."""
        fused, cnn, label, unknown = self._content
        color = MODE_COLORS[fused] if fused else "#555555"
        name = Text(
            MODE_NAMES[fused] if fused else "no decision yet",
            style="bold" if fused else "dim",
            justify="center",
        )
        if unknown:
            name = Text("unknown: IMU orientation stale", style="bold #f0a020", justify="center")
        below = Text.assemble(
            "CNN ", mode_text(cnn), "   true ", mode_text(label), justify="center"
        )
        height, width = self.size.height, max(1, self.size.width)
        extra = self._switching_line()  # shown when there is a row for it
        if height >= 7:
            extra = extra if height >= 8 else []
            big = Text(
                "\n".join(big_letters(fused or "--")), style=f"bold {color}", justify="center"
            )
            group = [big, name, below, *extra]
            if height >= 10 + len(extra):  # centred when taller
                group.insert(0, Text("\n" * max(0, (height - 8 - len(extra)) // 2 - 1)))
            return Group(*group)
        if extra and height >= 4:
            height -= len(extra)  # the band gives a row to the switches line
        else:
            extra = []
        if height <= 1:
            tail = ["  ", *self._switching_line()][: 2 if self._switching_line() else 0]
            return Group(Text.assemble(mode_text(fused), " ", name, "  ", below, *tail))
        rows = max(1, height - 2)  # a band as tall as the rows left for it
        letters = fused or "--"
        band_style = f"bold #000000 on {color}"
        band = Text(justify="left", no_wrap=True)  # centred by hand: "center" strips the band
        pad = min(width, max(8, width // 2))
        margin = " " * ((width - pad) // 2)
        for r in range(rows):
            cell = letters if r == (rows - 1) // 2 else ""
            band.append(margin)
            band.append(cell.center(pad), style=band_style)
            if r < rows - 1:
                band.append("\n")
        return Group(band, name, below, *extra)

    _switching: tuple = (None, None)  # (switches in the last minute, walker's mode)

    def present_switching(self, switches: int | None, walker: str | None = None) -> None:
        """How often the fused decision switched in the last minute (None: not counted)
        and, on mock devices, the walker's locomotion mode: the line under the labels."""
        content = (switches, mode_name(walker))
        if content != self._switching:
            self._switching = content
            self.refresh()

    def _switching_line(self) -> list:
        switches, walker = self._switching
        if switches is not None or walker:
            parts: list = []
            if switches is not None:
                parts.append(f"switches {switches} in the last minute")
            if walker:  # mock devices: the mode an operator keys, for practice
                parts += ["   " if parts else "", "walker ", mode_text(walker)]
            return [Text.assemble(*parts, style="dim", justify="center")]
        return []
