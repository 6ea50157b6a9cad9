"""`walkcap bench`: every figure that has a goal, measured on mock devices.

Each function measures one thing and returns plain numbers; `run_all` collects them as
results with their goals. Numbers depend on the machine: the report says which it was.
"""

from __future__ import annotations

import os
import platform
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from capture.config import Config
from capture.errors import CaptureError


@dataclass
class Result:
    name: str
    value: float
    unit: str
    goal: float | None
    better: str  # lower | higher
    note: str = ""

    @property
    def met(self) -> bool | None:
        if self.goal is None or not np.isfinite(self.value):
            return None
        return self.value <= self.goal if self.better == "lower" else self.value >= self.goal

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "value": round(float(self.value), 4),
            "unit": self.unit,
            "goal": self.goal,
            "better": self.better,
        }


def machine() -> dict:
    import torch

    cpu = platform.processor() or ""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    mem_gb = 0.0
    try:
        mem_gb = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError):
        pass
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "memory_gib": round(mem_gb, 1),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "platform": platform.platform(),
        "load_avg_1min": round(os.getloadavg()[0], 2),
    }


def rss_mib(pid: int | str = "self") -> float:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


def renderer_skipped(camera) -> int:
    """Frames the mock rig's renderer skipped when it fell behind (counted among the
    camera's errors), from the camera's status; 0 for other cameras."""
    return int((camera.details or {}).get("renderer_skipped", 0)) if camera else 0


def rss_growth_mib_per_min(samples: list, after_s: float = 60.0) -> tuple[float, float]:
    """Slope (least squares) of the host's RSS in (elapsed s, MiB, ...) samples after the
    first `after_s` (warm-up allocates), and the slope over the last half of those alone:
    memory that levels off shows a second figure near 0, a leak shows two alike."""

    def slope(rows):
        if len(rows) < 3:
            return float("nan")
        t, m = np.array([r[0] for r in rows]) / 60.0, np.array([r[1] for r in rows])
        return float(np.polyfit(t, m, 1)[0])

    settled = [r for r in samples if r[0] >= after_s]
    return slope(settled), slope(settled[len(settled) // 2 :])


def classifier(path: str | None = None):
    """The bundled model; an untrained network of the same shape (same cost) without it."""
    from capture.live.pipeline import CNN_THREADS
    from inference.errors import InferenceError
    from inference.model import load_classifier

    try:
        return load_classifier(path or None, threads=CNN_THREADS)
    except InferenceError:
        import torch

        from inference.model import Classifier, TerrainCNN

        return Classifier(TerrainCNN(), {}, torch.device("cpu"))


class LatencyLog:
    """Every frame's latency in one float64 array, allocated (and touched) up front for the
    frames expected: the soak measures the session's memory, so the bench's own record must
    not grow with it (8 bytes a frame, a quarter of a deque of Python floats).

    A latency sink of the session (Session.add_latency_sink): appends come from the
    pipeline thread, reads from the bench's, each under the log's own lock.
    """

    def __init__(self, expected_frames: int) -> None:
        self._values = np.full(max(int(expected_frames), 1024), np.nan)
        self._n = 0
        self._lock = threading.Lock()

    def append(self, ms: float) -> None:
        with self._lock:
            if self._n == len(self._values):  # longer than expected: grow rarely, by doubling
                self._values = np.concatenate([self._values, np.full(len(self._values), np.nan)])
            self._values[self._n] = ms
            self._n += 1

    __call__ = append  # the session calls its sinks

    def __len__(self) -> int:
        return self._n

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        return self.since(0) if dtype is None else self.since(0).astype(dtype)

    def since(self, k: int) -> np.ndarray:
        """A copy of the latencies from the k-th frame on."""
        with self._lock:
            return self._values[k : self._n].copy()


@dataclass
class SessionRun:
    fps: float
    imu_hz: int
    seconds: float
    frames: int
    latency_ms: np.ndarray
    dropped: int  # camera buffer + recorder queue + frames skipped by the simulator
    renderer_skipped: int  # of those, skipped by the mock rig's renderer (it fell behind)
    record_bytes: int
    record_seconds: float
    path: str
    sync_p99_ms: float
    rss_mib: list  # (elapsed s, MiB of this process, MiB of the mock rig's process)
    pipeline_priority: str = ""  # how the pipeline thread was scheduled
    lab_received: dict | None = None  # with lab tools: what the LSL inlet and Foxglove got


def session_run(
    fps: float,
    imu_hz: int,
    seconds: float,
    folder: str,
    *,
    clf=None,
    sample_every_s: float = 0.0,
    on_sample=None,
    lab_tools: bool = False,
) -> SessionRun:
    """A real mock session (devices, pipeline, recorder) for `seconds`, recording.

    `lab_tools`: with LSL outlets pulled by an inlet and a Foxglove server whose client
    subscribes to every topic, as a lab running both would.
    """
    from capture.live.session import Session
    from capture.live.trials import SubjectInfo

    cfg = Config()
    cfg.camera.fps = fps
    cfg.imu.rate_hz = imu_hz
    if imu_hz > 100:  # beyond the 1-series: a 600-series model on a line that carries it
        cfg.imu.emulate = "MTi-630"
        cfg.imu.baudrate = 921600
    cfg.session.recordings = folder
    cfg.simulator.loop = True  # the walk repeats for as long as the run lasts
    session = Session(cfg, classifier=clf or classifier(), auto_label=True)
    session.start()
    peers = _LabPeers(session, cfg) if lab_tools else None
    log = LatencyLog(seconds * fps * 1.2)
    session.add_latency_sink(log)
    memory = []
    rig_pid = session.rig_pid
    try:
        session.start_recording(SubjectInfo(subject="BENCH", condition="bench"))
        t0 = time.monotonic()
        next_sample = t0
        seen = 0
        while time.monotonic() - t0 < seconds and not session.finished.is_set():
            if sample_every_s and time.monotonic() >= next_sample:
                memory.append(
                    (
                        round(time.monotonic() - t0, 1),
                        round(rss_mib(), 1),
                        round(rss_mib(rig_pid), 1) if rig_pid is not None else float("nan"),
                    )
                )
                if on_sample is not None:
                    recent = log.since(seen)  # since the last sample
                    seen += len(recent)
                    on_sample(session.snapshot(), memory[-1], recent)
                next_sample += sample_every_s
            time.sleep(0.05)
        snap = session.snapshot()
    finally:
        if peers is not None:
            peers.close()
        stats = session.stop()
    # Read once the pipeline has stopped: every frame it counted, and no other.
    latencies = log.since(0)
    cam = snap.camera
    return SessionRun(
        fps=fps,
        imu_hz=imu_hz,
        seconds=seconds,
        frames=len(latencies),
        latency_ms=latencies,
        dropped=(cam.dropped + cam.errors if cam else 0) + (stats.dropped if stats else 0),
        renderer_skipped=renderer_skipped(cam),
        record_bytes=stats.bytes_written if stats else 0,
        record_seconds=stats.duration_s if stats else 0.0,
        path=stats.path if stats else "",
        sync_p99_ms=snap.sync.get("p99_ms", float("nan")),
        rss_mib=memory,
        pipeline_priority=session.pipeline_priority,
        lab_received=dict(peers.received) if peers is not None else None,
    )


class _LabPeers:
    """The lab's side of the lab tools, on loopback: an LSL inlet pulling walkcap's IMU and
    terrain streams and a Foxglove client subscribed to every topic."""

    def __init__(self, session, cfg) -> None:
        import asyncio

        from capture.labtools.connections import LabTools

        cfg.lsl.enabled = True
        cfg.foxglove.enabled = True
        cfg.foxglove.port = 0
        self.lab = LabTools(session, cfg).start()
        if self.lab.problems:
            raise CaptureError("; ".join(self.lab.problems))
        self._halt = threading.Event()
        self.received = {"lsl": 0, "foxglove": 0}
        self._threads = [
            threading.Thread(target=self._pull_lsl, daemon=True),
            threading.Thread(
                target=lambda: asyncio.run(self._watch(self.lab.foxglove.url)), daemon=True
            ),
        ]
        for t in self._threads:
            t.start()

    def _pull_lsl(self) -> None:
        from capture.labtools.lsl import pylsl

        lsl = pylsl()
        inlets = []
        for name in ("walkcap IMU", "walkcap Terrain"):
            found = lsl.resolve_byprop("name", name, 1, 5.0)
            if found:
                inlets.append(lsl.StreamInlet(found[0]))
        while not self._halt.wait(0.02):
            for inlet in inlets:
                samples, _ = inlet.pull_chunk(timeout=0.0)
                self.received["lsl"] += len(samples)

    async def _watch(self, url: str) -> None:
        import asyncio
        import json

        import websockets

        async with websockets.connect(url, subprotocols=["foxglove.sdk.v1"]) as ws:
            subscribed = False
            while not self._halt.is_set():
                try:
                    msg = await asyncio.wait_for(ws.recv(), 0.2)
                except TimeoutError:
                    continue
                if isinstance(msg, str):
                    info = json.loads(msg)
                    if info.get("op") == "advertise" and not subscribed:
                        subs = [
                            {"id": i, "channelId": ch["id"]}
                            for i, ch in enumerate(info["channels"])
                        ]
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                        subscribed = True
                else:
                    self.received["foxglove"] += 1

    def close(self) -> None:
        self._halt.set()
        for t in self._threads:
            t.join(timeout=3.0)
        self.lab.stop()


REPLAY_MINUTES = 2.0  # the trial `replay_speedup` replays: minutes at 45 fps, as users record


def replay_results(folder: str, minutes: float = REPLAY_MINUTES, runs: int = 3) -> list[Result]:
    """`walkcap replay` of a synthesized trial of `minutes` at 45 fps (capture.bench.scale),
    the whole command in a fresh process as a user runs it (capture.bench.replay): times
    real time on the median wall time of `runs`, and the CPU time of both processes."""
    from capture.bench.replay import replay_trial
    from capture.bench.scale import synthesize

    path = synthesize(Path(folder) / "B01_indoor_t01.mcap", minutes)
    try:
        run = replay_trial(path, runs=runs)
    finally:
        path.unlink(missing_ok=True)
    note = f"{run.frames} frames at 45 fps, the whole command"
    return [
        Result("replay_speedup", run.speedup, "x", 20, "higher", note),
        Result(
            "replay_cpu_speedup",
            run.cpu_speedup,
            "x",
            None,
            "higher",
            "recorded time over CPU time, both processes",
        ),
    ]


def run_all(seconds: float = 15.0, progress=print) -> list[Result]:
    """Every benchmark, in order; `progress` gets a line per step."""
    from capture.bench.components import (
        bench_cnn,
        bench_fusion,
        bench_method_update,
        bench_parse_rate,
        bench_preprocess,
        bench_record,
        bench_sim_frame,
    )
    from inference.fusion import METHOD_TABLE

    results: list[Result] = []
    progress("Xbus parser")
    results.append(
        Result("xbus_parse_rate", bench_parse_rate(2.0), "messages/s", 200_000, "higher")
    )
    progress("simulator")
    results.append(Result("sim_frame", bench_sim_frame(200), "ms", 5.0, "lower"))
    progress("preprocessing")
    pre = bench_preprocess(200)
    results.append(
        Result(
            "preprocess_frame",
            pre["numpy_median_ms"],
            "ms",
            2.0,
            "lower",
            f"Open3D backend {pre.get('open3d_median_ms', float('nan')):.2f} ms",
        )
    )
    progress("CNN")
    cnn = bench_cnn(500)
    results.append(
        Result(
            "cnn_frame",
            cnn["cnn_frame_ms"],
            "ms",
            1.0,
            "lower",
            f"walk: {cnn['walk_patches_occupied']:.0%} of patches, a band of "
            f"{cnn['walk_band_rows']:.0%} of rows; noise images "
            f"{cnn['cnn_frame_busy_ms']:.2f} ms",
        )
    )
    results.append(Result("cnn_batch_rate", cnn["cnn_batch_rate"], "frames/s", 2000, "higher"))
    progress("fusion")
    fusion = bench_fusion(20000)
    results.append(Result("fusion_update", fusion["fusion_update_us"], "us", 5.0, "lower"))
    # each method with a bound of its own, the cheaper bound first
    for spec in sorted((m for m in METHOD_TABLE if m.bench_us), key=lambda m: m.bench_us):
        us = bench_method_update(spec.name, 20000)
        name = "fusion_update_" + spec.name.replace("+", "_")
        results.append(Result(name, us, "us", spec.bench_us, "lower"))
    results.append(
        Result(
            "fusion_speedup_vs_paper_loop",
            fusion["speedup"],
            "x",
            None,
            "higher",
            f"numpy transcription {fusion['paper_loop_us']:.1f} us",
        )
    )
    clf = classifier()
    with tempfile.TemporaryDirectory() as tmp:
        for fps, imu_hz in ((15.0, 100), (45.0, 400)):
            progress(f"mock session {fps:g} fps, IMU {imu_hz} Hz, {seconds:g} s")
            run = session_run(fps, imu_hz, seconds, tmp, clf=clf)
            lat = run.latency_ms
            tag = f"{fps:g}fps"
            results.append(Result(f"latency_p50_{tag}", float(np.median(lat)), "ms", None, "lower"))
            results.append(
                Result(
                    f"latency_p99_{tag}",
                    float(np.percentile(lat, 99)),
                    "ms",
                    10.0,
                    "lower",
                    f"pipeline thread {run.pipeline_priority}",
                )
            )
            skipped = (
                f"{run.renderer_skipped} skipped by the mock renderer"
                if run.renderer_skipped
                else ""
            )
            results.append(Result(f"dropped_{tag}", run.dropped, "frames", 0, "lower", skipped))
            if fps == 45.0:
                results.append(Result("sync_error_p99_45fps", run.sync_p99_ms, "ms", 1.0, "lower"))
                rate = run.record_bytes / max(run.record_seconds, 1e-9) / 1e6
                results.append(Result("record_rate_45fps", rate, "MB/s", 2.5, "lower"))
                results.append(
                    Result(
                        "record_bytes_per_frame",
                        run.record_bytes / max(run.frames, 1),
                        "bytes",
                        None,
                        "lower",
                    )
                )
            else:
                progress(f"walkcap replay of a {REPLAY_MINUTES:g}-minute trial at 45 fps, 3 runs")
                results += replay_results(tmp)
                progress(f"the same with LSL outlets and a Foxglove client, {seconds:g} s")
                lab = session_run(fps, imu_hz, seconds, tmp, clf=clf, lab_tools=True)
                p50 = float(np.median(lab.latency_ms))
                results.append(Result("latency_p50_15fps_lab_tools", p50, "ms", None, "lower"))
                results.append(
                    Result(
                        "latency_p99_15fps_lab_tools",
                        float(np.percentile(lab.latency_ms, 99)),
                        "ms",
                        10.0,
                        "lower",
                    )
                )
                results.append(
                    Result(
                        "lab_tools_latency_cost_p50",
                        p50 - float(np.median(lat)),
                        "ms",
                        1.0,
                        "lower",
                        f"LSL inlet got {lab.lab_received['lsl']} samples, Foxglove client "
                        f"{lab.lab_received['foxglove']} messages",
                    )
                )
    progress("recorder alone (synthetic frames)")
    rec = bench_record(45, 10)
    results.append(
        Result(
            "record_rate_synthetic_45fps", rec.get("mb_per_s", float("nan")), "MB/s", 2.5, "lower"
        )
    )
    return results
