"""A widget drawn line by line from cached strips (Textual's line API).

The image and the profile change with every frame; building their few dozen lines as
plain segments costs a fraction of rendering the same text through Rich every time.
"""

from __future__ import annotations

import logging

from rich.segment import Segment
from rich.style import Style
from textual.geometry import Size
from textual.strip import Strip
from textual.widget import Widget

from tui.widgets.pacing import IMAGE_HZ, Pacer

log = logging.getLogger(__name__)

Line = list[tuple[str, Style | None]]  # (text, style) runs; None: the widget's own style


class CachedLines(Widget):
    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self._strips: list[Strip] | None = None
        self._built_for: Size | None = None

    def build_lines(self, width: int, height: int) -> list[Line]:
        raise NotImplementedError

    def invalidate(self) -> None:
        """The content changed: rebuild on the next draw."""
        self._strips = None
        self.refresh()

    def render_line(self, y: int) -> Strip:
        size = self.size
        if self._strips is None or self._built_for != size:
            base = self.rich_style
            strips = []
            try:
                lines = self.build_lines(size.width, size.height)
            except Exception:  # a drawing fault must never end a session that records
                log.exception("%s could not be drawn", type(self).__name__)
                lines = [[("(display error: see tui.log)", None)]]
            for line in lines[: size.height]:
                segments = [
                    Segment(text, base + style if style else base) for text, style in line if text
                ]
                strips.append(Strip(segments).adjust_cell_length(size.width, base))
            self._strips, self._built_for = strips, size
        if y < len(self._strips):
            return self._strips[y]
        return Strip.blank(size.width, self.rich_style)


class FrameLines(CachedLines):
    """Lines drawn from one frame's data, at most IMAGE_HZ new frames a second: the same
    frame (`key`) again costs nothing, and a new one within 1/IMAGE_HZ of the last waits
    for the next (the first shows at once)."""

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self._key: object = None
        self._pacer = Pacer(IMAGE_HZ)

    def _admit(self, key: object) -> bool:
        """True when the frame `key` is to be shown now (a None key always is)."""
        if key is not None and key == self._key:
            return False
        if key is not None and not self._pacer.due(urgent=self._key is None):
            return False
        self._key = key
        return True

    @property
    def shown_key(self) -> object:
        """The frame the widget shows (it lags a new frame by at most 1/IMAGE_HZ)."""
        return self._key
