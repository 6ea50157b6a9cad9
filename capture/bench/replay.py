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


# A frame's stages as replay runs them: (process, stage, module, function) timed by their
# thread's CPU time.
STAGES = (
    ("reader", "preprocessing", "inference.preprocess", "preprocess_ranges"),
    ("reader", "fitting the profile", "inference.features", "fit_profile"),
    (
        "reader",
        "encoding the cloud (and depth, truth of an older format)",
        "capture.corpus.replay",
        "_frame_messages",
    ),
    ("host", "CNN, batches of 16", "inference.model", "Classifier.predict_batch"),
    (
        "host",
        "encoding image, preprocessing, orientation",
        "capture.recording.encode",
        "encode_preprocessing",
    ),
    ("host", "fusion, features' classification, tilt", "capture.live.pipeline", "Pipeline.process"),
    ("host", "handing messages to the writer", "capture.recording.writer", "Recorder._put"),
    ("host", "writer: compression (zstd)", "capture.recording.chunks", "_ZstdAtLevel.compress"),
    (
        "host",
        "writer: the rest (messages, chunks, files)",
        "capture.recording.writer",
        "Recorder._run",
    ),
)
_WRITER = ("writer: compression (zstd)", "writer: the rest (messages, chunks, files)")


def stage_cpu(path: str | os.PathLike, frames: int = 2000, skip: int = 200) -> dict:
    """CPU time a frame of each stage (ms), replaying the trial at `path` in one process
    (the reader's work and the host's in turn, each stage timed by its thread's CPU time),
    over `frames` frames after the first `skip` (start-up and first calls left out; the
    writer thread, timed whole, is scaled to them); and the transfer of a step between the
    processes (packing, unpacking) on a sample of steps. "reading" is what is left of the
    main thread: the pass over the file (chunks, messages, frames, IMU samples, the gait
    detector, the orientation), and the little of the host's own that no stage names (its
    batches, the write calls). Returns {(process, stage): ms}."""
    import contextlib
    import importlib
    import itertools
    import time

    from capture.config import Config
    from capture.corpus import replay as R
    from capture.recording import topics as T
    from capture.recording.reader import open_recording

    rec = open_recording(path)
    count = rec.topics[T.DEPTH].count if T.DEPTH in rec.topics else 0
    skip = min(skip, count // 10)  # a short trial: a tenth of it left out
    frames = min(frames, count - skip - 1)  # the last step carries no frame
    if frames < 10:
        raise CaptureError(f"{path}: {count} frames: too few to time a replay's stages")
    clock = time.thread_time
    spent: dict = {}
    counting = [False]

    def timed(key, function):
        def wrapper(*args, **kwargs):
            start = clock()
            try:
                return function(*args, **kwargs)
            finally:
                if counting[0] or key[1] in _WRITER:
                    spent[key] = spent.get(key, 0.0) + clock() - start

        return wrapper

    every = R.replay_steps

    def steps(*args, **kwargs):
        for k, step in enumerate(every(*args, **kwargs)):
            if k == skip:
                counting[0], spent["main"] = True, -clock()
            if k == skip + frames:
                break
            yield step
        spent["main"] += clock()
        counting[0] = False

    with contextlib.ExitStack() as patches:
        for process, name, module, function in STAGES:
            owner = importlib.import_module(module)
            *outer, attribute = function.split(".")
            for part in outer:
                owner = getattr(owner, part)
            original = getattr(owner, attribute)
            setattr(owner, attribute, timed((process, name), original))
            patches.callback(setattr, owner, attribute, original)
        R.replay_steps = steps
        patches.callback(setattr, R, "replay_steps", every)
        with tempfile.TemporaryDirectory() as tmp:
            R.replay(path, Config(), output=Path(tmp) / "stages.mcap", reader_process=False)
    out = {}
    for key, seconds in spent.items():
        if isinstance(key, tuple):
            whole = key[1] in _WRITER  # timed over every frame written
            out[key] = seconds / (frames + skip if whole else frames) * 1e3
    compression = out.get(("host", _WRITER[0]), 0.0)
    out[("host", _WRITER[1])] = out.get(("host", _WRITER[1]), 0.0) - compression
    on_main = sum(v for (_, stage), v in out.items() if stage not in _WRITER)
    reading = "reading: chunks, messages, frames, IMU, gait, orientation (+ host's rest)"
    out[("reader", reading)] = spent["main"] / frames * 1e3 - on_main
    # the transfer between the processes, on a sample of steps
    config = Config()
    sample = list(
        itertools.islice(every(path, config.preprocess, config.mounting), skip, skip + 300)
    )
    start = clock()
    packed = [R._packed(("frame", s)) for s in sample]
    middle = clock()
    for p in packed:
        R._unpacked(p)
    end = clock()
    out[("reader", "sending (packing)")] = (middle - start) / len(sample) * 1e3
    out[("host", "receiving (unpacking)")] = (end - middle) / len(sample) * 1e3
    return out
