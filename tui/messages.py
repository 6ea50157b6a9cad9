"""The app's own messages: what the session workers report back to the UI thread."""

from __future__ import annotations

from pathlib import Path

from textual.message import Message


class SessionStarted(Message):
    """The devices are open and the pipeline runs."""


class SessionFailed(Message):
    """Opening the devices or loading the model failed; `error` is one line for the user."""

    def __init__(self, error: str) -> None:
        super().__init__()
        self.error = error


class RecordingStarted(Message):
    def __init__(self, path: Path) -> None:
        super().__init__()
        self.path = path


class RecordingStopped(Message):
    """`stats` is the recorder's final RecorderStats (None if nothing was recording)."""

    def __init__(self, stats: object | None, path: Path | None) -> None:
        super().__init__()
        self.stats = stats
        self.path = path


class RecordingFailed(Message):
    def __init__(self, error: str) -> None:
        super().__init__()
        self.error = error


class SessionStopped(Message):
    """The session stopped (devices closed, any recording finalised): the app may exit."""


class CorrectionsSaved(Message):
    def __init__(self, path: Path) -> None:
        super().__init__()
        self.path = path


class PreflightDone(Message):
    """The pre-flight check finished; `report` is a capture.live.preflight.PreflightReport."""

    def __init__(self, report: object) -> None:
        super().__init__()
        self.report = report


class NoticePosted(Message):
    """A notice for the operator (tui.widgets.notices.Notice), from any thread."""

    def __init__(self, notice, title: str, message: str, severity: str, timeout, markup: bool):
        super().__init__()
        self.notice = notice
        self.title, self.message, self.severity = title, message, severity
        self.timeout, self.markup = timeout, markup
