"""The app's own messages: what the session workers report back to the UI thread."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from textual.message import Message

from capture.live.preflight import PreflightReport
from capture.recording.writer import RecorderStats
from tui.widgets.notices import Notice


class SessionStarted(Message):
    """The devices are open and the pipeline runs."""


@dataclass
class SessionFailed(Message):
    """Opening the devices or loading the model failed."""

    error: str  # one line for the user


@dataclass
class RecordingStarted(Message):
    path: Path


@dataclass
class RecordingStopped(Message):
    stats: RecorderStats | None  # the recorder's final figures (None: nothing was recording)
    path: Path | None


@dataclass
class RecordingFailed(Message):
    error: str


class SessionStopped(Message):
    """The session stopped (devices closed, any recording finalised): the app may exit."""


@dataclass
class CorrectionsSaved(Message):
    path: Path


@dataclass
class PreflightDone(Message):
    """The pre-flight check finished."""

    report: PreflightReport


@dataclass
class NoticePosted(Message):
    """A notice for the operator, from any thread, with App.notify's arguments."""

    notice: Notice
    title: str
    message: str
    severity: str
    timeout: float | None
    markup: bool
