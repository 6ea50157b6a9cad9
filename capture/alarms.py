"""Live alarms of a trial: stream gaps, a camera stall, low disk, a filling writer queue,
a pipeline failure. What the operator must see at once, in words, without reading numbers.

Gaps are counted per trial on the timestamps the recorder writes (host receive times), by
the rule `walkcap info` applies to the file afterwards (capture.reader.find_gaps): an
interval longer than GAP_PERIODS x the stream's configured period (the camera's fps, the
IMU's rate, which the file's metadata records). So the live count and the file's agree.
"""

from __future__ import annotations

import collections
import shutil
import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

GAP_PERIODS = 3.0  # an interval longer than this many periods is a gap
DISK_MINUTES_LOW = 10.0  # free disk below this many minutes of recording: alarm
QUEUE_FULL = 0.5  # the recorder's queue above this fraction: alarm
RECENT_S = 5.0  # an ended gap, a pipeline failure: shown this long
SILENT_SHOWN_S = 0.3  # a stream silent this long shows while it lasts (shorter ones count)
_MEDIAN_WINDOW = 512  # intervals the running median is taken over
_DISK_EVERY_NS = 2_000_000_000

STREAMS = ("camera", "imu")


class GapCounter:
    """Gaps in one regular stream, counted as samples arrive (thread-safe).

    The period is the configured one; without it, the running median interval."""

    def __init__(self, period_s: float | None = None) -> None:
        self._period_ns = period_s * 1e9 if period_s else None
        self._lock = threading.Lock()
        self._last_ns: int | None = None
        self._intervals: collections.deque[int] = collections.deque(maxlen=_MEDIAN_WINDOW)
        self._median_ns = 0.0
        self._since_median = 0
        self.count = 0
        self.longest_s = 0.0
        self.last_gap: tuple[int, float] | None = None  # the last shown: (end ns, length s)

    def add(self, t_ns: int) -> float | None:
        """One sample's time; the gap's length in seconds when this sample ends one."""
        with self._lock:
            last, self._last_ns = self._last_ns, t_ns
            if last is None or t_ns <= last:
                return None
            dt = t_ns - last
            gap = None
            if len(self._intervals) >= 2 and dt > GAP_PERIODS * self._median_ns:
                gap = dt * 1e-9
                self.count += 1
                self.longest_s = max(self.longest_s, gap)
                if gap >= SILENT_SHOWN_S:  # short ones count, and show in the trial's total
                    self.last_gap = (t_ns, gap)
            self._intervals.append(dt)
            if self._period_ns is not None:
                self._median_ns = self._period_ns
                return gap
            self._since_median += 1
            if self._since_median >= 32 or len(self._intervals) < 64:
                self._median_ns = float(np.median(self._intervals))
                self._since_median = 0
            return gap

    def silent_s(self, now_ns: int) -> float | None:
        """Seconds since the last sample when that is longer than a gap; else None."""
        with self._lock:
            if self._last_ns is None or len(self._intervals) < 2:
                return None
            silent = now_ns - self._last_ns
            return silent * 1e-9 if silent > GAP_PERIODS * self._median_ns else None


@dataclass
class Alarm:
    level: str  # "error" (red) | "warning" (amber)
    text: str  # words: "IMU: no data for 1.2 s"


@dataclass
class AlarmState:
    """The trial's gap counts and the alarms in force, for the UI and the status line."""

    gaps: dict[str, int] = field(default_factory=dict)  # stream -> gaps this trial
    longest_s: dict[str, float] = field(default_factory=dict)
    alarms: list[Alarm] = field(default_factory=list)
    disk_free_bytes: int | None = None
    disk_minutes: float | None = None  # at the measured write rate


def disk_minutes(free_bytes: int, bytes_per_s: float | None) -> float | None:
    return free_bytes / bytes_per_s / 60 if bytes_per_s and bytes_per_s > 0 else None


def recorder_alarms(stats: object | None) -> list[Alarm]:
    """The writer's queue filling up (the disk is slower than the data)."""
    depth = getattr(stats, "queue_depth", None)
    size = getattr(stats, "queue_size", None)
    if depth is None or not size or depth <= QUEUE_FULL * size:
        return []
    level = "error" if depth >= 0.9 * size else "warning"
    return [Alarm(level, f"writer queue {100 * depth // size:.0f} % full: the disk falls behind")]


def event_alarms(events: list, now_ns: int) -> list[Alarm]:
    """Pipeline failures of the last few seconds, whatever the pipeline reports."""
    horizon = now_ns - int(RECENT_S * 1e9)
    out = []
    for e in events:
        if e.device == "pipeline" and e.time_ns >= horizon:
            out.append(Alarm("error", f"pipeline {e.kind}: {e.message}"))
    return out[-2:]


class TrialAlarms:
    """Per-trial gap counters plus the checks that need no stream (disk, queue, events)."""

    def __init__(self, recordings: str | Path, periods_s: dict[str, float] | None = None) -> None:
        self.recordings = Path(recordings)
        self.periods_s = periods_s or {}  # stream -> configured period
        self.counters = self._counters()
        self.recording = False
        self.trial_gaps: dict[str, int] = {}  # the last trial's, once it ended
        self.write_rate: float | None = None  # bytes/s, the last measured
        self._disk_checked_ns = 0
        self._disk_free: int | None = None

    def new_trial(self) -> None:
        """Counts start again with each trial's file (samples feed them all the time, so a
        stall shows while no trial records, too)."""
        self.counters = self._counters()
        self.recording = True

    def _counters(self) -> dict[str, GapCounter]:
        return {s: GapCounter(self.periods_s.get(s)) for s in STREAMS}

    def end_trial(self) -> dict[str, int]:
        """The trial's gap counts per stream (kept in `trial_gaps` too)."""
        self.recording = False
        self.trial_gaps = {s: c.count for s, c in self.counters.items()}
        return self.trial_gaps

    def sample(self, stream: str, t_ns: int) -> None:
        """A sample or frame as the trial's file gets it, at its log time."""
        self.counters[stream].add(t_ns)

    def _disk(self, now_ns: int) -> int | None:
        if now_ns - self._disk_checked_ns >= _DISK_EVERY_NS:
            self._disk_checked_ns = now_ns
            try:
                folder = self.recordings
                while not folder.exists() and folder != folder.parent:
                    folder = folder.parent
                self._disk_free = shutil.disk_usage(folder).free
            except OSError:
                self._disk_free = None
        return self._disk_free

    def state(self, now_ns: int, recorder_stats: object | None, events: list) -> AlarmState:
        out = AlarmState()
        rate = getattr(recorder_stats, "bytes_per_s", None)
        if rate:
            self.write_rate = float(rate)
        out.disk_free_bytes = self._disk(now_ns)
        if out.disk_free_bytes is not None:
            out.disk_minutes = disk_minutes(out.disk_free_bytes, self.write_rate)
        if out.disk_minutes is not None and out.disk_minutes < DISK_MINUTES_LOW:
            out.alarms.append(Alarm("error", f"disk: {out.disk_minutes:.0f} min of recording left"))
        for stream, counter in self.counters.items():
            if self.recording:
                out.gaps[stream] = counter.count
                out.longest_s[stream] = counter.longest_s
            name = "IMU" if stream == "imu" else stream
            silent = counter.silent_s(now_ns)
            if silent is not None and silent >= SILENT_SHOWN_S:
                out.alarms.append(Alarm("error", f"{name}: no data for {silent:.1f} s"))
            elif counter.last_gap is not None:
                end, length = counter.last_gap
                if now_ns - end < RECENT_S * 1e9:
                    out.alarms.append(
                        Alarm("warning", f"{name}: gap of {length:.2f} s ended, data again")
                    )
        if self.recording and any(out.gaps.values()):  # the trial's file has holes
            longest = max(out.longest_s.values())
            counts = ", ".join(f"{'IMU' if s == 'imu' else s} {n}" for s, n in out.gaps.items())
            out.alarms.append(
                Alarm("warning", f"gaps this trial: {counts} (longest {longest:.2f} s)")
            )
        out.alarms += recorder_alarms(recorder_stats)
        out.alarms += event_alarms(events, now_ns)
        return out
