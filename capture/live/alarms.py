"""Live alarms of a trial: stream gaps, a camera stall, low disk, a filling writer queue,
a pipeline failure. What the operator must see at once, in words, without reading numbers.

Gaps are counted per trial by the definition `walkcap info` applies to the file afterwards
(capture.recording.gaps): data the device produced and the file lacks, on the device's own sequence
(frame index, IMU packet counter). Late delivery (a host stall with nothing lost) is its
own figure. So the live count and the file's agree.
"""

from __future__ import annotations

import shutil
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from capture.recording.gaps import GAP_PERIODS, MODULUS, OWN_CLOCK, Gap, Late, LossCounter
from devices import clock

if TYPE_CHECKING:
    from capture.recording.writer import RecorderStats

DISK_MINUTES_LOW = 10.0  # free disk below this many minutes of recording: alarm
QUEUE_FULL = 0.5  # the recorder's queue above this fraction: alarm
RECENT_S = 5.0  # an ended gap, a pipeline failure: shown this long
SILENT_SHOWN_S = 0.3  # a stream silent this long shows while it lasts (shorter ones count)
_DISK_EVERY_NS = 2_000_000_000
_DEFAULT_PERIODS = {"camera": 1 / 15, "imu": 1 / 100}

STREAMS = ("camera", "imu")
__all__ = ["GAP_PERIODS", "StreamCounter", "TrialAlarms"]


class StreamCounter:
    """One stream's gaps and late deliveries this trial, and how long it has been silent."""

    def __init__(self, stream: str, period_s: float | None = None) -> None:
        self.period_s = period_s or _DEFAULT_PERIODS[stream]
        self.loss = LossCounter(self.period_s, MODULUS[stream], OWN_CLOCK[stream])
        self._lock = threading.Lock()
        self._last_host_ns: int | None = None
        self.last_gap: tuple[int, float, bool] | None = None  # shown: (end ns, s, data lost)

    @property
    def count(self) -> int:
        return len(self.loss.loss.gaps)

    @property
    def longest_s(self) -> float:
        return self.loss.loss.longest_s

    def add(self, seq: int | None, device_ns: int | None, host_ns: int) -> Gap | Late | None:
        """One item as the file gets it: its device sequence number and time, its log time."""
        found = self.loss.add(seq, device_ns, host_ns)
        with self._lock:
            self._last_host_ns = host_ns
            if found is not None and found.length_s >= SILENT_SHOWN_S:
                self.last_gap = (host_ns, found.length_s, isinstance(found, Gap))
        return found

    def silent_s(self, now_ns: int) -> float | None:
        """Seconds since the last item when that is longer than a gap; else None."""
        with self._lock:
            if self._last_host_ns is None:
                return None
            silent = now_ns - self._last_host_ns
            return clock.seconds(silent) if silent > GAP_PERIODS * self.period_s * 1e9 else None


@dataclass
class Alarm:
    level: str  # "error" (red) | "warning" (amber)
    text: str  # words: "IMU: no data for 1.2 s"


@dataclass
class AlarmState:
    """The trial's gap counts and the alarms in force, for the UI and the status line."""

    gaps: dict[str, int] = field(default_factory=dict)  # stream -> gaps this trial
    longest_s: dict[str, float] = field(default_factory=dict)
    missing: dict[str, int] = field(default_factory=dict)  # items lost by the device's count
    late: dict[str, int] = field(default_factory=dict)  # late deliveries, nothing lost
    alarms: list[Alarm] = field(default_factory=list)
    disk_free_bytes: int | None = None
    disk_minutes: float | None = None  # at the measured write rate


def disk_minutes(free_bytes: int, bytes_per_s: float | None) -> float | None:
    return free_bytes / bytes_per_s / 60 if bytes_per_s and bytes_per_s > 0 else None


def recorder_alarms(stats: RecorderStats | None) -> list[Alarm]:
    """The writer's queue filling up (the disk is slower than the data)."""
    if stats is None:
        return []
    depth, size = stats.queue_depth, stats.queue_size
    if not size or depth <= QUEUE_FULL * size:
        return []
    level = "error" if depth >= 0.9 * size else "warning"
    return [Alarm(level, f"writer queue {100 * depth // size:.0f} % full: the disk falls behind")]


def event_alarms(events: list, now_ns: int) -> list[Alarm]:
    """Pipeline failures of the last few seconds, whatever the pipeline reports."""
    horizon = now_ns - clock.to_ns(RECENT_S)
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
        self.trial_late: dict[str, int] = {}
        self.write_rate: float | None = None  # bytes/s, the last measured
        self._disk_checked_ns = 0
        self._disk_free: int | None = None

    def new_trial(self) -> None:
        """Counts start again with each trial's file (samples feed them all the time, so a
        stall shows while no trial records, too)."""
        self.counters = self._counters()
        self.recording = True

    def _counters(self) -> dict[str, StreamCounter]:
        return {s: StreamCounter(s, self.periods_s.get(s)) for s in STREAMS}

    def end_trial(self) -> dict[str, int]:
        """The trial's gap counts per stream (kept in `trial_gaps`, late deliveries in
        `trial_late`)."""
        self.recording = False
        self.trial_gaps = {s: c.count for s, c in self.counters.items()}
        self.trial_late = {s: len(c.loss.loss.late) for s, c in self.counters.items()}
        return self.trial_gaps

    def sample(self, stream: str, seq: int | None, device_ns: int | None, host_ns: int) -> None:
        """A sample or frame as the trial's file gets it: the device's sequence number and
        time, and the host's receive (log) time."""
        self.counters[stream].add(seq, device_ns, host_ns)

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

    def state(self, now_ns: int, recorder_stats: RecorderStats | None, events: list) -> AlarmState:
        out = AlarmState()
        rate = recorder_stats.bytes_per_s if recorder_stats is not None else None
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
                out.missing[stream] = counter.loss.loss.missing
                out.late[stream] = len(counter.loss.loss.late)
            name = "IMU" if stream == "imu" else stream
            silent = counter.silent_s(now_ns)
            if silent is not None and silent >= SILENT_SHOWN_S:
                out.alarms.append(Alarm("error", f"{name}: no data for {silent:.1f} s"))
            elif counter.last_gap is not None:
                end, length, lost = counter.last_gap
                if now_ns - end < RECENT_S * 1e9:
                    text = (
                        f"{name}: gap of {length:.2f} s ended, data again"
                        if lost
                        else f"{name}: {length:.2f} s late (the computer stalled), nothing lost"
                    )
                    out.alarms.append(Alarm("warning", text))
        if self.recording and any(out.gaps.values()):  # the trial's file has holes
            longest = max(out.longest_s.values())
            counts = ", ".join(f"{'IMU' if s == 'imu' else s} {n}" for s, n in out.gaps.items())
            out.alarms.append(
                Alarm("warning", f"gaps this trial: {counts} (longest {longest:.2f} s)")
            )
        if self.recording and any(out.late.values()):  # all there, but delivered late
            counts = ", ".join(f"{'IMU' if s == 'imu' else s} {n}" for s, n in out.late.items())
            out.alarms.append(Alarm("warning", f"late deliveries this trial: {counts}"))
        out.alarms += recorder_alarms(recorder_stats)
        out.alarms += event_alarms(events, now_ns)
        return out
