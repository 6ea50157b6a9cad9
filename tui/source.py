"""What the screens are driven by: the live Session, or a recording being replayed.

The live screen only pulls `snapshot()` and sends these commands; anything with this
surface can drive it (capture.live.session.Session does; tests use a fake; replay its own).
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol, runtime_checkable

from capture.live.session import Snapshot, SubjectInfo


class Source(Protocol):
    def start(self) -> None: ...
    def stop(self) -> object: ...
    def snapshot(self) -> Snapshot: ...
    def set_label(self, mode: str) -> object: ...
    def undo_label(self) -> object: ...
    def add_marker(self, note: str = "", time_ns: int | None = None) -> None: ...
    def start_recording(self, info: SubjectInfo) -> Path: ...
    def stop_recording(self) -> object: ...

    @property
    def recording(self) -> bool: ...

    @property
    def label(self) -> str | None: ...


@runtime_checkable
class Playback(Protocol):
    """Extra controls of a replayed recording (play, pause, seek)."""

    playing: bool

    def toggle_play(self) -> None: ...
    def seek(self, delta_s: float) -> None: ...
    def position(self) -> tuple[float, float]: ...  # (seconds from start, duration)
