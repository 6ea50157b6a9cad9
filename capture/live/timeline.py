"""What the pipeline thread publishes for the UI: the latest frame's result, the last
TIMELINE_S of decisions beside the labels, frame counts, latencies and decision switches."""

from __future__ import annotations

import collections
import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from capture.live.pipeline import FrameResult
from devices import clock

TIMELINE_S = 20.0
SWITCHES_S = 60.0  # the live screen counts the fused decision's switches over this long


@dataclass
class TimelineEntry:
    index: int
    time_ns: int
    label: str | None
    cnn: int
    fused: int | None = None  # filled in when the fused decision for this frame arrives
    voted: int | None = None
    truth: str | None = None


class SwitchCounter:
    """Changes of the final fused decision over the last `span_s` of frame time."""

    def __init__(self, span_s: float) -> None:
        self.span_ns = clock.to_ns(span_s)
        self._last: int | None = None
        self._times: collections.deque[int] = collections.deque()

    def add(self, time_ns: int, final: int | None) -> None:
        """The final decision made at `time_ns` (None: none made then)."""
        if final is not None:
            if self._last is not None and final != self._last:
                self._times.append(time_ns)
            self._last = final
        while self._times and self._times[0] < time_ns - self.span_ns:
            self._times.popleft()

    def count(self) -> int:
        return len(self._times)


@dataclass
class Published:
    """A copy of what the pipeline published, taken at one instant."""

    latest: FrameResult | None
    timeline: list[TimelineEntry]
    frames: int
    stale_frames: int
    switches_last_minute: int
    latency_ms: dict  # p50, p99 (empty before the first frame)


class FrameTimeline:
    """The pipeline thread's results as the UI reads them. Thread-safe: the pipeline thread
    publishes, the UI copies out with `published()`."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._latest: FrameResult | None = None
        self._entries: collections.deque[TimelineEntry] = collections.deque()
        self._by_index: dict[int, TimelineEntry] = {}
        self._latencies: collections.deque[float] = collections.deque(maxlen=2000)
        self._latency_sinks: list[Callable[[float], None]] = []
        self._frames = 0
        self._stale_frames = 0
        self._switches = SwitchCounter(SWITCHES_S)

    def publish(self, r: FrameResult, label: str | None, truth: str | None, votes: bool) -> None:
        """Frame `r`, labelled `label`; its fused output fills in the earlier entries it
        decides. `votes`: the fusion's final decision is its vote."""
        entry = TimelineEntry(r.index, r.time_ns, label, r.cnn_decision, truth=truth)
        horizon = r.time_ns - clock.to_ns(TIMELINE_S)
        with self._lock:
            self._latest = r
            self._frames += 1
            self._stale_frames += not r.decided
            self._entries.append(entry)
            self._by_index[r.index] = entry
            while self._entries and self._entries[0].time_ns < horizon:
                self._by_index.pop(self._entries.popleft().index, None)
            fused = r.fused
            if fused is not None:
                e = self._by_index.get(fused.frame)
                if e is not None:
                    e.fused = fused.decision
                if fused.voted is not None:
                    e = self._by_index.get(fused.voted_frame)
                    if e is not None:
                        e.voted = fused.voted
                self._switches.add(r.time_ns, fused.voted if votes else fused.decision)
            self._latencies.append(r.latency_ms)
            for sink in self._latency_sinks:
                sink(r.latency_ms)

    def new_trial(self) -> None:
        """Stale frames are counted per trial, as the file counts them."""
        with self._lock:
            self._stale_frames = 0

    def add_latency_sink(self, sink: Callable[[float], None]) -> None:
        """Call `sink(ms)` with every frame's pipeline latency, in frame order, on the
        pipeline thread under the lock that counts the frame."""
        with self._lock:
            self._latency_sinks.append(sink)

    def published(self) -> Published:
        with self._lock:
            latencies = np.asarray(self._latencies) if self._latencies else None
            return Published(
                latest=self._latest,
                timeline=list(self._entries),  # entries only gain a late fused decision
                frames=self._frames,
                stale_frames=self._stale_frames,
                switches_last_minute=self._switches.count(),
                latency_ms={}
                if latencies is None
                else {
                    "p50": float(np.median(latencies)),
                    "p99": float(np.percentile(latencies, 99)),
                },
            )
