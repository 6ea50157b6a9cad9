"""`walkcap bench --replay FILE`: `walkcap replay` of a real trial, as its user runs it.

The whole command in a fresh process each run (its start-up, the IMU pass, the model and
the reader process included): wall time, CPU time (user + system, the reader process
included: steadier than wall time on a shared machine) and peak memory (the largest
resident set of the processes), the medians of a few runs. A trial of realistic length
(minutes at 45 fps) is what makes the figure mean what a user sees.
"""

from __future__ import annotations

import os
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from capture.errors import CaptureError


@dataclass
class ReplayRun:
    path: str
    frames: int
    recorded_s: float
    wall_s: list[float]
    cpu_s: list[float]
    peak_rss_mib: list[float]

    @property
    def speedup(self) -> float:
        """Recorded time over the median wall time: times real time."""
        return self.recorded_s / float(np.median(self.wall_s))

    @property
    def cpu_speedup(self) -> float:
        """Recorded time over the median CPU time: what an otherwise idle machine could not
        beat with one core, and reaches with as many cores as replay keeps busy."""
        return self.recorded_s / float(np.median(self.cpu_s))


def replay_trial(path: str | os.PathLike, runs: int = 3, command=None) -> ReplayRun:
    """`runs` replays of the trial at `path` into a temporary folder. `command`: the
    argument list that runs walkcap (default: this Python, `-m tui.cli`)."""
    from capture.recording import topics as T
    from capture.recording.reader import open_recording

    path = Path(path)
    rec = open_recording(path)
    if T.DEPTH not in rec.topics:
        raise CaptureError(f"{path}: no depth frames to replay")
    from capture.bench.launch import measured

    command = command or [sys.executable, "-m", "tui.cli"]
    walls, cpus, peaks = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(runs):
            out = Path(tmp) / f"replay{k}.mcap"
            with open(Path(tmp) / "stderr.txt", "w+b") as err:
                # its waited-for reader process included
                run = measured([*command, "replay", str(path), "-o", str(out)], stderr=err)
                if run.returncode != 0:
                    err.seek(0)
                    last = err.read().decode(errors="replace").strip().splitlines()[-1:]
                    raise CaptureError(f"replay of {path} failed: {' '.join(last)}")
            walls.append(run.wall_s)
            cpus.append(run.cpu_s)
            peaks.append(run.peak_mib)
            out.unlink(missing_ok=True)
    return ReplayRun(str(path), rec.topics[T.DEPTH].count, rec.duration_s, walls, cpus, peaks)
