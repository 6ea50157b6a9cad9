"""The CNN's input: the leveled 100 x 100 binary image, as large as the widget allows."""

from __future__ import annotations

import numpy as np
from rich.style import Style

from tui.widgets.lines import FrameLines, Line
from tui.widgets.raster import fit_binary_image

_DIM = Style(dim=True)
_FLAG = Style(bold=True, color="#f0a020")


class BinaryImage(FrameLines):
    """Half-blocks when the full image fits, braille (pooled if need be) otherwise.

    Drawn as inference.preprocess makes it: row 0 highest, column 0 nearest (seen from
    the walker's left side), so up is up and the walker looks to the right.
    """

    DEFAULT_CSS = """
    BinaryImage { color: $text; }
    """

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self._image: np.ndarray | None = None
        self._flag = ""

    def present(self, image: np.ndarray | None, flag: str = "", key: object = None) -> None:
        """`key` identifies the frame (FrameLines)."""
        if self._admit(key):
            self._image, self._flag = image, flag
            self.invalidate()

    def build_lines(self, width: int, height: int) -> list[Line]:
        if self._image is None:
            return [[("no frame yet", _DIM)]]
        lines, factor, style = fit_binary_image(self._image, width, height - 1)
        out: list[Line] = [[(line, None)] for line in lines]
        w, h = self._image.shape[1], self._image.shape[0]
        pooled = f", shown 1:{factor}" if factor > 1 else ""
        # the longest wording that fits: abbreviated deliberately, never cut
        captions = (f"leveled image {w} x {h} cells{pooled}", f"{w} x {h} cells{pooled}", "")
        flag = self._flag if len(self._flag) + 2 <= width else self._flag.split("_")[0]
        caption = next((c for c in captions if len(c) + len(flag) + 2 <= width), "")
        out.append([(caption, _DIM), (f"  {flag}"[:width] if flag else "", _FLAG)])
        return out
