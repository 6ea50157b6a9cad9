"""The CNN's five class probabilities as horizontal bars in the mode colours."""

from __future__ import annotations

import numpy as np
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

    def render(self) -> Text:
        width = max(4, self.size.width - 8)
        finite = self._probs is not None and np.isfinite(self._probs).any()
        best = int(np.nanargmax(self._probs)) if finite else -1
        text = Text(no_wrap=True)
        for i, mode in enumerate(MODES):
            p = float(self._probs[i]) if self._probs is not None else 0.0
            p = p if np.isfinite(p) else 0.0
            strong = i == best
            text.append(f"{mode} ", style="bold" if strong else "")
            text.append(
                bar(p, width), style=f"bold {MODE_COLORS[mode]}" if strong else MODE_COLORS[mode]
            )
            text.append(f" {p:.2f}", style="bold" if strong else "dim")
            if i < len(MODES) - 1:
                text.append("\n")
        return text
