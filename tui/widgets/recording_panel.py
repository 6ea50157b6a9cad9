"""The trial being recorded: file, elapsed time, size, write rate, writer queue, gaps."""

from __future__ import annotations

import collections
from pathlib import Path

from rich.table import Table
from rich.text import Text
from textual.widget import Widget

from capture.recording.writer import RecorderState, RecorderStats
from devices import clock
from tui.widgets.pacing import Pacer


def human_bytes(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB"):
        if abs(n) < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} GB"


def clock_text(seconds: float) -> str:
    s = max(0, int(seconds))
    return f"{s // 3600:d}:{s // 60 % 60:02d}:{s % 60:02d}"


class ByteRate:
    """Bytes per second over the last few seconds, from (time, total bytes) readings."""

    def __init__(self, window_s: float = 3.0) -> None:
        self._window_ns = clock.to_ns(window_s)
        self._readings: collections.deque[tuple[int, int]] = collections.deque()

    def add(self, time_ns: int, total: int) -> float | None:
        if self._readings and (total < self._readings[-1][1] or time_ns < self._readings[-1][0]):
            self._readings.clear()  # a new file
        if not self._readings or time_ns > self._readings[-1][0]:
            self._readings.append((time_ns, total))
        while len(self._readings) > 2 and time_ns - self._readings[0][0] > self._window_ns:
            self._readings.popleft()
        (t0, b0), (t1, b1) = self._readings[0], self._readings[-1]
        return (b1 - b0) / clock.seconds(t1 - t0) if t1 > t0 else None


def recording_rows(
    stats: RecorderStats | None,
    elapsed_s: float | None,
    path: Path | None,
    next_trial: str = "",
    write_rate: float | None = None,
    idle: str = "○ not recording",
    gaps: dict | None = None,
) -> list[tuple[str, str, str]]:
    """(label, value, style) lines for the panel, formatted (`stats` None: no figures yet)."""
    if elapsed_s is None:
        return [(idle, "", "bold")] + ([(next_trial, "", "dim")] if next_trial else [])
    rows = [("● REC", clock_text(elapsed_s), "bold")]
    if stats is not None and stats.state == RecorderState.FAILED:
        rows.append(("FAILED", stats.message or "the recording stopped", "bold #e04040"))
    file = path or (stats.path if stats is not None else None)
    if file is not None:  # two lines at the name's last "_" rather than cut anywhere
        head, sep, tail = Path(file).name.rpartition("_")
        rows.append(("file", f"{head}{sep}\n{tail}" if sep else tail, ""))
    size = stats.bytes_written if stats is not None else None
    if size is not None:
        rows.append(("size", human_bytes(size), ""))
    rows.append(("write", f"{human_bytes(write_rate)}/s" if write_rate is not None else "—", ""))
    depth, capacity = (stats.queue_depth, stats.queue_size) if stats is not None else (None, 0)
    if depth is not None:  # items waiting for the writer thread; full means lost data
        busy = bool(capacity) and depth > capacity / 2
        pct = f"{100 * depth / capacity:.0f} % full" if capacity else f"{depth} items"
        rows.append(("queue", pct, "bold #f0a020" if busy else ""))
    if gaps is not None:
        cam, imu = gaps.get("camera", 0), gaps.get("imu", 0)
        rows.append(("gaps", f"camera {cam}, IMU {imu}", "bold #f0a020" if cam or imu else ""))
    dropped = stats.dropped if stats is not None else None
    rows.append(("dropped", f"{dropped or 0} messages", "bold #e04040" if dropped else ""))
    return rows


def compact_text(rows: list[tuple[str, str, str]], width: int, height: int) -> Text:
    """The panel's rows run together into `height` lines of `width`: the first row (REC and
    the time, or what the record key starts), then what is wrong (a styled row: failed,
    queue filling, gaps, drops), then the rest; the file name is the banner's."""
    first, rest = rows[:1], [r for r in rows[1:] if r[0] != "file"]
    ordered = first + [r for r in rest if r[2]] + [r for r in rest if not r[2]]
    text, line, used = Text(no_wrap=True, overflow="ellipsis"), 0, 0
    for i, (label, value, style) in enumerate(ordered):
        piece = f"{label} {value}".strip() if i else f"{label} {value}".strip()
        sep = " · " if used else ""
        if used and used + len(sep) + len(piece) > width:
            if line + 1 >= height:
                break
            text.append("\n")
            line, used, sep = line + 1, 0, ""
        if i == 0:
            color = "#e04040" if label.startswith("●") else ""
            text.append(piece, style=f"bold {color}")
        else:
            text.append(sep + piece, style=style)
            piece = sep + piece
        used += len(piece)
    return text


class RecordingPanel(Widget):
    DEFAULT_CSS = """
    RecordingPanel { height: 1fr; }
    """

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self._rows: list[tuple[str, str, str]] = []
        self._rate = ByteRate()
        self._pacer = Pacer()

    def present(
        self,
        stats: RecorderStats | None,
        elapsed_s: float | None,
        path: Path | None,
        next_trial: str = "",
        now_ns: int = 0,
        idle: str = "○ not recording",
        gaps: dict | None = None,
    ) -> None:
        """`next_trial` describes what the record key would start (shown while idle)."""
        size = stats.bytes_written if stats is not None else None
        rate = self._rate.add(now_ns, size) if size is not None else None
        if rate is None and stats is not None:
            rate = stats.bytes_per_s or None
        rows = recording_rows(stats, elapsed_s, path, next_trial, rate, idle, gaps)
        if rows == self._rows:
            return
        urgent = [r for r in rows if r[0] not in ("size", "write", "queue")] != [
            r for r in self._rows if r[0] not in ("size", "write", "queue")
        ]
        if self._pacer.due(urgent):
            self._rows = rows
            self.refresh()  # fixed height: no relayout (it would redraw the whole screen)

    def render(self) -> Table | Text:
        lines = sum(1 + value.count("\n") for _, value, _ in self._rows)
        if 0 < self.size.height < lines:  # a short terminal: the same, in fewer lines
            return compact_text(self._rows, self.size.width, self.size.height)
        table = Table.grid(padding=(0, 1))
        table.add_column(style="dim", no_wrap=True, min_width=5)
        table.add_column(overflow="fold")  # the file name wraps, never cut
        for i, (label, value, style) in enumerate(self._rows):
            if i == 0:
                color = "#e04040" if label.startswith("●") else ""
                table.add_row(Text(label, style=f"bold {color}"), Text(value, style=style))
            else:
                table.add_row(
                    Text(label, style=style if not value else ""), Text(value, style=style)
                )
        return table
