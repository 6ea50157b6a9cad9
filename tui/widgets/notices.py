"""The notice line: what just happened (a trial saved, a device lost, a drill), one line
under the alarms. Notices never float over the live panels: the strips and the decision
stay readable while they show."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from rich.text import Text
from textual.widget import Widget

_STYLES = {
    "error": "bold #e04040",
    "warning": "bold #f0a020",
    "information": "",
}


@dataclass(frozen=True)
class Notice:
    """One notice as the operator reads it: its local clock time, its words, its weight."""

    text: str
    severity: str = "information"  # information | warning | error
    clock: str = field(default_factory=lambda: time.strftime("%H:%M:%S"))
    short: str = ""  # the same in fewer words, shown where `text` does not fit the line


class NoticeLine(Widget):
    """The latest notice with its time; the earlier ones are in ~/.cache/walkcap/tui.log."""

    DEFAULT_CSS = """
    NoticeLine { height: 1; }
    """

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self._notice: Notice | None = None

    @property
    def notice(self) -> Notice | None:
        return self._notice

    def present(self, notice: Notice | None) -> None:
        if notice != self._notice:
            self._notice = notice
            self.refresh()  # fixed height: no relayout

    def render(self) -> Text:
        line = Text(no_wrap=True, overflow="ellipsis")
        notice = self._notice
        if notice is None:
            line.append(" no notices", style="dim")
            return line
        stamp = f" {notice.clock} "
        line.append(stamp, style="dim")
        style = _STYLES.get(notice.severity, "")
        line.append(fit(notice, self.size.width - len(stamp)), style=style)
        return line


def fit(notice: Notice, room: int) -> str:
    """The notice's words for `room` columns: the whole text, else its short form, else
    the short form cut with an ellipsis (the log has the whole text)."""
    if len(notice.text) <= room or not notice.short:
        return notice.text
    return notice.short
