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

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self._content: tuple = (None, None, None)

    def present(self, fused: int | str | None, cnn: int | str | None, label: str | None) -> None:
        content = (mode_name(fused), mode_name(cnn), mode_name(label))
        if content != self._content:
            self._content = content
            self.refresh()

    def render(self) -> Group:
        fused, cnn, label = self._content
        color = MODE_COLORS[fused] if fused else "#555555"
        big = Text("\n".join(big_letters(fused or "--")), style=f"bold {color}", justify="center")
        name = Text(
            MODE_NAMES[fused] if fused else "no decision yet",
            style="bold" if fused else "dim",
            justify="center",
        )
        below = Text.assemble(
            "CNN ", mode_text(cnn), "   true ", mode_text(label), justify="center"
        )
        return Group(big, name, below, *self._switching_line())

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
