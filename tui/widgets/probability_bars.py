"""The CNN's five class probabilities as horizontal bars in the mode colours."""
from __future__ import annotations

import numpy as np
from rich.table import Table
from rich.text import Text
from textual.widget import Widget

from devices.frames import MODES
from tui.widgets.modes import MODE_COLORS

_EIGHTHS = " ▏▎▍▌▋▊▉█"


def bar(fraction: float, width: int) -> str:
    """A bar `fraction` of `width` cells long, to an eighth of a cell."""
    fraction = min(1.0, max(0.0, float(fraction))) if np.isfinite(fraction) else 0.0
    eighths = round(fraction * width * 8)
    full, part = divmod(eighths, 8)
    return ("█" * full + (_EIGHTHS[part] if part else "")).ljust(width)


class ProbabilityBars(Widget):
    DEFAULT_CSS = """
    ProbabilityBars { height: 5; }
    """

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self._probs: np.ndarray | None = None

    def present(self, probabilities: np.ndarray | None) -> None:
        probs = None if probabilities is None else np.asarray(probabilities, dtype=np.float64)
        if probs is None and self._probs is None:
            return
        if probs is not None and self._probs is not None and np.array_equal(probs, self._probs):
            return
        self._probs = probs
        self.refresh()

    def render(self) -> Table:
        width = max(4, self.size.width - 9)
        table = Table.grid(padding=(0, 1))
        table.add_column(no_wrap=True)
        table.add_column(no_wrap=True)
        table.add_column(no_wrap=True, justify="right")
        best = int(np.argmax(self._probs)) if self._probs is not None else -1
        for i, mode in enumerate(MODES):
            p = float(self._probs[i]) if self._probs is not None else 0.0
            style = f"bold {MODE_COLORS[mode]}" if i == best else MODE_COLORS[mode]
            table.add_row(Text(mode, style="bold" if i == best else ""),
                          Text(bar(p, width), style=style),
                          Text(f"{p:.2f}"[1:] if p < 1 else "1.0", style="bold" if i == best else "dim"))
        return table
