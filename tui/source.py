"""What the screens are driven by: the live Session, or a recording being replayed.

The screens pull `snapshot()` and send these commands; anything with this surface can drive
them: capture.live.session.Session live, tui.replay.ReplaySource for a recording (which is
also a `Playback`), a fake in the UI tests. The screens use nothing else of their source.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Protocol, runtime_checkable

from capture.live.session import Snapshot
from capture.live.trials import SubjectInfo
from capture.recording.labels import LabelChange

if TYPE_CHECKING:
    from capture.live.alarms import TrialAlarms
    from capture.recording.writer import RecorderStats


class Source(Protocol):
    trial_notice: str  # why the last recording has another trial number than asked ("": none)
    trial: SubjectInfo | None  # the form of the recording in progress (None: none)
    alarms: TrialAlarms | None  # each trial's gaps, counted as it records (None: never records)

    def start(self) -> None: ...
    def stop(self) -> RecorderStats | None: ...  # a recording still open, finalised
    def snapshot(self) -> Snapshot: ...
    def set_label(self, mode: str) -> LabelChange: ...
    def undo_label(self) -> LabelChange | None: ...  # None: nothing to undo
    def add_marker(self, note: str = "", time_ns: int | None = None) -> None: ...
    def start_recording(
        self, info: SubjectInfo, existing: str = "next", folder: str | Path | None = None
    ) -> Path: ...
    def stop_recording(self) -> RecorderStats | None: ...
    def inject(self, device: str, fault: str, **kw) -> None: ...  # --drills, mock devices only

    @property
    def recording(self) -> bool: ...

    @property
    def label(self) -> str | None: ...


@runtime_checkable
class Playback(Protocol):
    """A replayed recording's own controls: play, pause, seek, and label corrections
    written to a new file."""

    path: Path  # the recording shown
    playing: bool
    subject_info: SubjectInfo | None  # the recording's session form (None: it has none)
    corrections: list[LabelChange]  # made in this replay, oldest first
    saved_path: Path | None  # where the corrections were saved last (None: not yet)

    @property
    def unsaved(self) -> bool: ...  # corrections or markers not saved yet

    def toggle_play(self) -> None: ...
    def seek(self, delta_s: float) -> None: ...
    def position(self) -> tuple[float, float]: ...  # (seconds from start, duration)
    def save_corrections(self, path: str | Path | None = None) -> Path: ...
