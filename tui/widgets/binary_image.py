"""The CNN's input: the leveled 100 x 100 binary image, as large as the widget allows."""
from __future__ import annotations

import numpy as np
from rich.text import Text
from textual.widget import Widget

from tui.widgets.raster import fit_binary_image


class BinaryImage(Widget):
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
        self._key: object = None

    def present(self, image: np.ndarray | None, flag: str = "", key: object = None) -> None:
        """`key` identifies the frame: the same key again costs nothing."""
        if key is not None and key == self._key:
            return
        self._key = key
        self._image, self._flag = image, flag
        self.refresh()

    def render(self) -> Text:
        if self._image is None:
            return Text("no frame yet", style="dim")
        cols, rows = self.size.width, self.size.height - 1
        lines, factor, style = fit_binary_image(self._image, cols, rows)
        text = Text("\n".join(lines))
        caption = f"{self._image.shape[1]}x{self._image.shape[0]} {style}"
        if factor > 1:
            caption += f" 1:{factor}"
        text.append("\n" + caption, style="dim")
        if self._flag:
            text.append(f"  {self._flag}", style="bold #f0a020")
        return text
