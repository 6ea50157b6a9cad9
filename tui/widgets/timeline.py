"""The last ~20 s as coloured strips: operator label, CNN decision, fused decision
(the paper's Fig. 8, live), plus the simulator's truth when there is one."""

from __future__ import annotations

from collections.abc import Sequence

from rich.text import Text
from textual.widget import Widget

from devices import clock
from tui.widgets.modes import MODE_COLORS, mode_name

SPAN_S = 20.0
_NAME_WIDTH = 6


def strip_cells(
    entries: Sequence, field: str, now_ns: int, width: int, span_s: float = SPAN_S
) -> list[str | None]:
    """The mode shown in each of `width` columns; a column covers span_s / width seconds.

    The latest entry in a column wins; a column without a frame (a gap) or whose frame has
    no value is None; columns before the first frame are "" (nothing happened yet).
    """
    cells: list[str | None] = [None] * width
    if width <= 0:
        return cells
    start = now_ns - clock.to_ns(span_s)
    per_col = span_s * 1e9 / width
    if entries:
        first = int((entries[0].time_ns - start) // per_col)
        cells[: max(0, min(first, width))] = [""] * max(0, min(first, width))
    else:
        cells = [""] * width
    for e in entries:
        col = int((e.time_ns - start) // per_col)
        if 0 <= col < width:
            value = mode_name(getattr(e, field))
            if value is not None:
                cells[col] = value
    return cells


def strip_text(cells: list[str | None]) -> Text:
    """Runs of colour; a run long enough carries its mode's letters at its start."""
    text = Text()
    i = 0
    while i < len(cells):
        j = i
        while j < len(cells) and cells[j] == cells[i]:
            j += 1
        mode, n = cells[i], j - i
        if mode == "":
            text.append(" " * n)
        elif mode is None:
            text.append("·" * n, style="#444444")
        else:
            body = (mode + " " * (n - 2)) if n >= 3 else " " * n
            text.append(body, style=f"bold #000000 on {MODE_COLORS[mode]}")
        i = j
    return text


def axis_text(width: int, span_s: float = SPAN_S) -> Text:
    left, mid, right = f"-{span_s:g} s", f"-{span_s / 2:g} s", "now"
    line = [" "] * width
    for pos, label in ((0, left), (width // 2 - len(mid) // 2, mid), (width - len(right), right)):
        for k, ch in enumerate(label):
            if 0 <= pos + k < width:
                line[pos + k] = ch
    return Text("".join(line), style="dim")


class TimelineStrips(Widget):
    DEFAULT_CSS = """
    TimelineStrips { height: auto; }
    """

    ROWS = (("true", "label"), ("CNN", "cnn"), ("fused", "fused"))

    def __init__(self, span_s: float = SPAN_S, **kwargs) -> None:
        super().__init__(**kwargs)
        self.span_s = span_s
        self._entries: list = []
        self._now_ns = 0
        self._key: object = None

    def present(self, entries: Sequence, now_ns: int) -> None:
        """Redrawn when a frame arrives, a decision fills in, or time moves a column on."""
        width = max(1, self.size.width - _NAME_WIDTH)
        column_ns = int(self.span_s * 1e9 / width)
        last = entries[-4:] if entries else []
        key = (
            now_ns // max(1, column_ns),
            len(entries),
            tuple((e.index, e.label, e.cnn, e.fused, e.truth) for e in last),
            hash(tuple(e.label for e in entries)),  # a correction relabels earlier frames too
            width,
        )
        if key == self._key:
            return
        self._key = key
        rows = len(self._rows())
        self._entries, self._now_ns = list(entries), now_ns
        # The height follows the rows: a new one (the simulator's truth) needs a new layout,
        # or the time axis below it is cut off.
        self.refresh(layout=len(self._rows()) != rows)

    def _rows(self) -> list[tuple[str, str]]:
        rows = list(self.ROWS)
        if any(e.truth for e in self._entries):
            rows.append(("sim", "truth"))
        return rows

    def render(self) -> Text:
        width = max(1, self.size.width - _NAME_WIDTH)
        rows = self._rows()
        text = Text(no_wrap=True)
        for name, field in rows:
            text.append(f"{name:<{_NAME_WIDTH}}", style="bold")
            text.append_text(
                strip_text(strip_cells(self._entries, field, self._now_ns, width, self.span_s))
            )
            text.append("\n")
        text.append(" " * _NAME_WIDTH)
        text.append_text(axis_text(width, self.span_s))
        return text
