"""The camera thread's hand-over to the pipeline thread, and runs of frames the pipeline
did not classify (counted as one event each, not one per frame)."""

from __future__ import annotations

import collections
import threading

from devices.base import DeviceEvent


class FrameInbox:
    """The camera thread's hand-over to the pipeline thread: (frame, recorder) items, up to
    `size` (a hiccup of the pipeline is caught up, as the camera's buffer did). Full in real
    time, the oldest item goes unclassified (it is already recorded); `blocking`, the camera
    thread waits for the pipeline instead."""

    def __init__(self, size: int = 8) -> None:
        self._items: collections.deque[tuple] = collections.deque()
        self.size = max(1, size)
        self._closed = False
        self.blocking = False
        self._cond = threading.Condition()

    def put(self, item: tuple) -> tuple | None:
        """Hand `item` over; the oldest one it pushed out, if any."""
        with self._cond:
            while self.blocking and len(self._items) >= self.size and not self._closed:
                self._cond.wait(0.1)
            dropped = self._items.popleft() if len(self._items) >= self.size else None
            self._items.append(item)
            self._cond.notify_all()
            return dropped

    def take(self, timeout_s: float) -> tuple | None:
        with self._cond:
            if not self._items and timeout_s > 0:
                self._cond.wait(timeout_s)
            item = self._items.popleft() if self._items else None
            self._cond.notify_all()
            return item

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()


class Streak:
    """A run of frames that failed the same way, as two events: when it starts, and when
    it ends (`settle` frames in a row go through again, or the trial stops) with how many
    frames it cost. A flaky classifier is one run, not an event per frame."""

    def __init__(self, device: str, kind: str, why: str, settle: int = 30) -> None:
        self.device, self.kind, self.why = device, kind, why
        self.settle = settle
        self.count = 0
        self.first = ""
        self._good = 0
        self._lock = threading.Lock()

    def fail(self, t_ns: int, message: str) -> DeviceEvent | None:
        with self._lock:
            self._good = 0
            self.count += 1
            if self.count > 1:
                return None
            self.first = message
        text = f"{message} ({self.why}; frames not classified from here on are counted)"
        return DeviceEvent(t_ns, self.device, self.kind, text, {"count": 1})

    def ok(self, t_ns: int, final: bool = False) -> DeviceEvent | None:
        with self._lock:
            n, first = self.count, self.first
            if n == 0:
                return None
            self._good += 1
            if self._good < self.settle and not final:
                return None
            self.count = self._good = 0
        text = f"{n} frames not classified: {self.why} (first: {first})"
        return DeviceEvent(t_ns, self.device, self.kind, text, {"count": n})
