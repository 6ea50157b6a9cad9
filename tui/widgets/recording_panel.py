"""The trial being recorded: file, elapsed time, size, write rate, writer queue."""
from __future__ import annotations

from pathlib import Path

from rich.table import Table
from rich.text import Text
from textual.widget import Widget

# RecorderStats field names, with fallbacks so the panel reads any version of the stats.
_SIZE = ("bytes_written", "bytes", "size_bytes")
_RATE = ("write_rate_bps", "bytes_per_s", "write_rate")
_QUEUE = ("queue_depth", "queue", "queued")
_MESSAGES = ("messages", "messages_written")
_DROPPED = ("dropped", "messages_dropped")


def _stat(stats: object, names: tuple[str, ...]):
    for n in names:
        value = getattr(stats, n, None)
        if value is not None:
            return value
    return None


def human_bytes(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB"):
        if abs(n) < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} GB"


def clock_text(seconds: float) -> str:
    s = max(0, int(seconds))
    return f"{s // 3600:d}:{s // 60 % 60:02d}:{s % 60:02d}"


def recording_rows(stats: object | None, elapsed_s: float | None, path: Path | None,
                   next_trial: str = "") -> list[tuple[str, str, str]]:
    """(label, value, style) lines for the panel, formatted."""
    if elapsed_s is None:
        return [("○ not recording", "", "bold")] + ([(next_trial, "", "dim")] if next_trial else [])
    rows = [("● REC", clock_text(elapsed_s), "bold")]
    file = path or _stat(stats, ("path",))
    if file is not None:
        rows.append(("file", Path(file).name, ""))
    size, rate = _stat(stats, _SIZE), _stat(stats, _RATE)
    if size is not None:
        rows.append(("size", human_bytes(size), ""))
    if rate is not None:
        rows.append(("write", f"{human_bytes(rate)}/s", ""))
    queue = _stat(stats, _QUEUE)
    if queue is not None:
        rows.append(("queue", str(queue), "bold #f0a020" if queue > 100 else ""))
    messages, dropped = _stat(stats, _MESSAGES), _stat(stats, _DROPPED)
    if messages is not None:
        rows.append(("msgs", str(messages), ""))
    if dropped:
        rows.append(("lost", str(dropped), "bold #e04040"))
    return rows


class RecordingPanel(Widget):
    DEFAULT_CSS = """
    RecordingPanel { height: auto; }
    """

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self._rows: list[tuple[str, str, str]] = []

    def present(self, stats: object | None, elapsed_s: float | None, path: Path | None,
                next_trial: str = "") -> None:
        """`next_trial` describes what the record key would start (shown while idle)."""
        rows = recording_rows(stats, elapsed_s, path, next_trial)
        if rows != self._rows:
            relayout = len(rows) != len(self._rows)
            self._rows = rows
            self.refresh(layout=relayout)

    def render(self) -> Table:
        table = Table.grid(padding=(0, 1))
        table.add_column(style="dim", no_wrap=True)
        table.add_column(no_wrap=True, overflow="ellipsis")
        for i, (label, value, style) in enumerate(self._rows):
            if i == 0:
                color = "#e04040" if label.startswith("●") else ""
                table.add_row(Text(label, style=f"bold {color}"), Text(value, style=style))
            else:
                table.add_row(Text(label, style=style if not value else ""), Text(value, style=style))
        return table
