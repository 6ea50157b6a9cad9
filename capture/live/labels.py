"""The operator's label book: each change of the true mode, and the mode in force."""

from __future__ import annotations

import threading

from capture.errors import CaptureError
from capture.recording.labels import UNDO, LabelChange
from devices.frames import MODES


class LabelBook:
    """The label changes of a session in the order they were made; an undo takes the last
    one back, and the mode before it applies again. Thread-safe: the UI keys, the camera
    thread labels from the simulator's truth, the pipeline thread reads."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._history: list[LabelChange] = []
        self.label: str | None = None  # the mode in force (None: none keyed yet)

    def change(self, mode: str, source: str, time_ns: int) -> LabelChange:
        """`mode` from `time_ns` on."""
        if mode not in MODES:
            raise CaptureError(f"unknown mode {mode!r} (one of {', '.join(MODES)})")
        change = LabelChange(time_ns, mode, source)
        with self._lock:
            self._history.append(change)
            self.label = mode
        return change

    def undo(self, time_ns: int) -> tuple[LabelChange, LabelChange] | None:
        """Take back the last change at `time_ns`: (the undo, the change undone), or None
        when there is nothing to undo. The undo's mode is "" when no mode is in force."""
        with self._lock:
            if not self._history:
                return None
            undone = self._history.pop()
            previous = self._history[-1].mode if self._history else None
            self.label = previous
        return LabelChange(time_ns, previous or "", UNDO), undone
