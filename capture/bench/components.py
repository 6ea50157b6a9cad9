"""Benchmarks of one component each: the Xbus parser, the simulator, preprocessing, the CNN,
fusion and the recorder. Each returns plain numbers; capture.bench collects them.
"""

from __future__ import annotations

import collections
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
import zstandard

from capture.bench.fuzz import SAMPLE_VALUES
from capture.corpus.dataset import render_synth_session
from capture.recording import topics as T
from capture.recording.reader import open_recording
from capture.recording.writer import Recorder
from devices.clock import now_ns
from devices.frames import CameraGeometry, ImuSample
from devices.rotations import mounting_matrix, quat_from_euler, quat_to_matrix
from devices.simulator import Simulator, make_course
from devices.simulator.synthetic import corridor_cloud, synthetic_frame
from devices.xbus import MID, XbusParser, build, encode_mtdata2
from inference.config import PreprocessConfig
from inference.errors import InferenceError
from inference.fusion import HmmFusion, make_fusion
from inference.fusion_design import N_MODES, PAPER_TRANSITION, paper_step
from inference.model import INPUT_SIZE, Classifier, TerrainCNN, load_classifier, occupied_patches
from inference.preprocess import BACKENDS as PREPROCESS_BACKENDS
from inference.preprocess import preprocess


def bench_parse_rate(seconds: float = 2.0) -> float:
    """MTData2 messages framed, checked and decoded per second of CPU time.

    Default outputs in float32 (a 73-byte frame), fed in 4 KiB chunks. CPU time, not wall
    time, so that other processes on a shared machine do not count against the parser.
    """
    frame = build(MID.MTDATA2, encode_mtdata2({**SAMPLE_VALUES, "packet_counter": 1}))
    per_chunk = max(1, 4096 // len(frame))
    chunk = frame * per_chunk
    parser = XbusParser()
    count = 0
    start = time.process_time()
    deadline = start + seconds
    while True:
        for _ in range(50):
            count += len(parser.feed(chunk))
        now = time.process_time()
        if now >= deadline:
            break
    return count / (now - start)


def bench_sim_frame(frames: int = 200) -> float:
    """Median milliseconds per rendered 224 x 171 frame (indoor course, seed 0, 15 fps)."""
    sim = Simulator(make_course("indoor", 0))
    times = []
    for k in range(frames):
        t = (k / 15.0) % sim.duration_s
        t0 = time.perf_counter()
        sim.render(t, index=k)
        times.append(time.perf_counter() - t0)
    return float(np.median(times) * 1e3)


def _bench_frames(count: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Level ground and a step seen from a swinging thigh, full resolution, 1 cm noise."""
    geometry = CameraGeometry()
    rays = geometry.rays().reshape(-1, 3).astype(np.float64)
    mount = mounting_matrix(0.0, 35.0)
    rng = np.random.default_rng(seed)
    frames = []
    for i in range(count):
        q = quat_from_euler(
            np.radians(rng.uniform(-3, 3)),
            np.radians(rng.uniform(-25, 10)),
            np.radians(rng.uniform(-180, 180)),
        )
        d = rays @ (quat_to_matrix(q) @ mount).T
        # Floor 0.55 m below the camera; every other frame a 0.15 m step from 0.6 m ahead.
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(d[:, 2] < 0, -0.55 / d[:, 2], np.inf)
            if i % 2:
                t_step = np.where(d[:, 2] < 0, -0.40 / d[:, 2], np.inf)
                t = np.where(np.hypot(d[:, 0], d[:, 1]) * t_step > 0.6, t_step, t)
        t = t + rng.uniform(-0.01, 0.01, len(t))
        valid = np.isfinite(t) & (t < geometry.max_range_m)
        xyz = (rays * np.where(valid, t, 0.0)[:, None]).astype(np.float32)
        frames.append(
            (
                xyz.reshape(geometry.height, geometry.width, 3),
                np.where(valid, 255, 0).astype(np.uint8).reshape(geometry.height, geometry.width),
                q,
            )
        )
    return frames


def bench_preprocess(frames: int = 200) -> dict:
    """Median milliseconds per frame, frame -> image, for the numpy and Open3D backends.

    Also each backend without outlier removal (`*_no_outliers_*`): leveling and cropping
    alone. `walkcap bench` reports the numpy backend's figure and the Open3D one's beside it.
    """
    data = _bench_frames(min(frames, 40))
    height, width = data[0][1].shape
    result: dict = {"frames": frames, "resolution": f"{width}x{height}"}
    for backend in PREPROCESS_BACKENDS:
        for suffix, outliers in (("", PreprocessConfig.outlier_min_points), ("_no_outliers", 0)):
            params = PreprocessConfig(backend=backend, outlier_min_points=outliers)
            preprocess(*data[0], params)  # warm-up (imports, caches)
            times, corridor = [], []
            for i in range(frames):
                xyz, confidence, q = data[i % len(data)]
                t0 = time.perf_counter()
                out = preprocess(xyz, confidence, q, params)
                times.append(time.perf_counter() - t0)
                corridor.append(len(out.cloud))
            name = backend + suffix
            result[f"{name}_median_ms"] = float(np.median(times) * 1e3)
            result[f"{name}_p95_ms"] = float(np.percentile(times, 95) * 1e3)
            result[f"{name}_corridor_points"] = int(np.median(corridor))
    return result


def bench_cnn(frames: int = 500, path: str | None = None, threads: int = 1) -> dict:
    """Single-frame latency (median ms) and batched throughput (frames/s) on the CPU.

    The images of a synthesized indoor walk (the sparse path's cost follows how much of an
    image is occupied), and, for the worst case, random noise images that occupy 40 % of
    the patches and take the dense path. The bundled model if it exists, else an
    untrained network (same cost). `threads` applies to the single-frame figures (1, as the
    live session runs the CNN); the batched figure uses every core.
    """
    walk = render_synth_session("indoor", 1)[0].images
    images = walk[np.arange(frames) % len(walk)]
    noise = np.random.default_rng(0).random((100, INPUT_SIZE, INPUT_SIZE)) < 0.03
    try:
        clf = load_classifier(path, device="cpu")
    except InferenceError:
        clf = Classifier(TerrainCNN(), {}, torch.device("cpu"))

    def one_frame_ms(images: np.ndarray) -> float:
        for img in images[:20]:
            clf.predict(img)
        times = []
        for img in images:
            t = time.perf_counter()
            clf.predict(img)
            times.append(time.perf_counter() - t)
        return float(np.median(times) * 1e3)

    before = torch.get_num_threads()
    try:
        torch.set_num_threads(threads)
        frame_ms, busy_ms = one_frame_ms(images), one_frame_ms(noise)
        torch.set_num_threads(os.cpu_count() or 1)
        clf.predict_batch(images[:32])
        t = time.perf_counter()
        clf.predict_batch(images)
        rate = frames / (time.perf_counter() - t)
    finally:
        torch.set_num_threads(before)
    # What sets the sparse path's cost: the share of occupied patches and of occupied rows.
    occupied = occupied_patches(images)
    rows = occupied.any(axis=2)
    span = [np.ptp(np.flatnonzero(r)) + 1 if r.any() else 0 for r in rows]
    return {
        "cnn_frame_ms": frame_ms,
        "cnn_frame_busy_ms": busy_ms,
        "cnn_batch_rate": float(rate),
        "walk_patches_occupied": float(np.median(occupied.mean(axis=(1, 2)))),
        "walk_band_rows": float(np.median(span) / rows.shape[1]),
    }


def bench_fusion(updates: int = 20000, window: int = 5, seed: int = 0) -> dict:
    """Median time of one fusion update (HmmFusion.push) against the numpy transcription.

    Returns {"fusion_update_us", "paper_loop_us", "speedup"}. Not a test: a figure to report.
    """
    rng = np.random.default_rng(seed)
    frames = rng.dirichlet(np.ones(N_MODES), size=updates + window)
    clock = time.perf_counter_ns

    fusion = HmmFusion(window, PAPER_TRANSITION)
    for row in frames[:window]:
        fusion.push(row)
    fast = []
    for row in frames[window:]:
        start = clock()
        fusion.push(row)
        fast.append(clock() - start)

    smooth = frames.copy()
    paper = []
    for t in range(window, len(frames)):
        start = clock()
        _, smooth[t] = paper_step(smooth[t - window : t], frames[t], PAPER_TRANSITION, window)
        paper.append(clock() - start)

    fast_us = float(np.median(fast)) / 1000.0
    paper_us = float(np.median(paper)) / 1000.0
    return {"fusion_update_us": fast_us, "paper_loop_us": paper_us, "speedup": paper_us / fast_us}


def bench_method_update(method: str, updates: int = 20000, seed: int = 0) -> float:
    """Median time of one `push` of a fusion method (inference.fusion.make_fusion), us."""
    rng = np.random.default_rng(seed)
    frames = rng.dirichlet(np.ones(N_MODES), size=updates + 10)
    clock = time.perf_counter_ns
    fusion = make_fusion(method)
    times = []
    if getattr(fusion, "takes_elevation", False):  # a thigh swinging 20 degrees at 1 Hz
        elevation = (-35 + 20 * np.sin(2 * np.pi * np.arange(len(frames)) / 15)).tolist()
        steps = getattr(fusion, "uses_steps", False)  # a gait event every 8 frames: 2 a stride
        for k, row in enumerate(frames):
            start = clock()
            if steps and k % 8 == 0:
                fusion.see_gait("heel_contact" if k % 16 == 0 else "toe_off")
            fusion.push(row, elevation[k])
            times.append(clock() - start)
    elif getattr(fusion, "uses_geometry", False):  # the push and the frame's geometry
        shown = rng.integers(-1, N_MODES, size=len(frames)).tolist()
        ahead = rng.integers(-1, N_MODES, size=len(frames)).tolist()
        for k, row in enumerate(frames):
            start = clock()
            fusion.push(row)
            fusion.see_geometry(shown[k], ahead[k])
            times.append(clock() - start)
    else:
        for row in frames:
            start = clock()
            fusion.push(row)
            times.append(clock() - start)
    return float(np.median(times[10:])) / 1000.0


def bench_record(
    fps: float = 45.0,
    seconds: float = 10.0,
    imu_hz: float = 100.0,
    folder: str | os.PathLike | None = None,
) -> dict:
    """Record `seconds` of synthetic data at `fps` as fast as possible; report the file's
    size per second of data and per frame (all topics: depth with 1 % range noise,
    confidence, corridor cloud, image, transform, inference, features, IMU at `imu_hz`)."""
    rng = np.random.default_rng(1)
    n_frames = int(round(fps * seconds))
    frames = [synthetic_frame(i, 0) for i in range(min(n_frames, 90))]  # reused, re-stamped
    clouds = [corridor_cloud(f) for f in frames]
    with tempfile.TemporaryDirectory(dir=folder) as tmp:
        path = Path(tmp) / "bench.mcap"
        rec = Recorder(
            path,
            metadata={"session": {"subject": "BENCH"}},
            queue_size=n_frames * 8 + int(imu_hz * seconds) + 16,
        )
        rec.start()
        t0 = now_ns()
        wall = time.perf_counter()
        imu_period = int(1e9 / imu_hz)
        next_imu = t0
        for i in range(n_frames):
            t = t0 + int(i * 1e9 / fps)
            while next_imu <= t:
                rec.write_imu(
                    ImuSample(
                        host_time_ns=next_imu + 1_000_000,
                        time_ns=next_imu,
                        packet_counter=(next_imu - t0) // imu_period,
                        sample_time_fine=int((next_imu - t0) // 100_000),
                        quaternion=np.array([1.0, 0, 0, 0]) + rng.normal(0, 1e-3, 4),
                        acceleration=np.array([0, 0, 9.81]) + rng.normal(0, 0.05, 3),
                        rate_of_turn=rng.normal(0, 0.01, 3),
                        status_word=3,
                    )
                )
                next_imu += imu_period
            f = frames[i % len(frames)]
            f = type(f)(
                index=i,
                device_time_ns=t,
                host_time_ns=t + 2_000_000,
                xyz=f.xyz,
                confidence=f.confidence,
                gray=f.gray,
                geometry=f.geometry,
                truth=f.truth,
            )
            rec.write_frame(f)
            cloud = clouds[i % len(frames)]
            image = np.zeros((100, 100), np.uint8)
            image[60 + int(10 * np.sin(i / 20)) :, :] = 1
            rec.write_processed(i, t, t + 2_000_000, cloud, image, np.array([1.0, 0, 0, 0]), "")
            probs = rng.dirichlet(np.ones(5))
            rec.write_inference(
                i,
                t,
                t + 8_000_000,
                probs,
                {
                    "frame_index": max(0, i - 2),
                    "decision": "LG",
                    "posterior": probs,
                    "voted": "LG",
                    "voted_frame_index": max(0, i - 3),
                },
            )
            rec.write_features(i, t, {"riser_m": 0.17, "tread_m": 0.3, "slope_deg": 0.0})
        stats = rec.close()
        elapsed = time.perf_counter() - wall
        size = path.stat().st_size
        by_topic = _compressed_by_topic(path)
    return {
        "fps": fps,
        "seconds": seconds,
        "frames": n_frames,
        "cloud_points": float(np.mean([len(c) for c in clouds])),
        "bytes": size,
        "mb_per_s": size / seconds / 1e6,
        "bytes_per_frame": size / n_frames,
        "write_s": elapsed,
        "realtime_factor": seconds / elapsed if elapsed else float("inf"),
        "dropped": stats.dropped,
        "state": stats.state,
        "mb_per_s_by_topic": {k: round(v / seconds / 1e6, 4) for k, v in by_topic.items()},
    }


def _compressed_by_topic(path: Path) -> dict[str, int]:
    """Approximate share of each topic: its messages zstd-compressed one second at a time,
    as the chunks are (the file compresses all topics of a chunk together)."""
    groups: dict[tuple[str, int], list[bytes]] = collections.defaultdict(list)
    rec = open_recording(path)
    for m in rec.messages(raw=True):
        data = (
            m.data.SerializeToString()
            if hasattr(m.data, "SerializeToString")
            else T.encode_json(m.data)
        )
        groups[(m.topic, (m.log_time_ns - (rec.start_ns or 0)) // 1_000_000_000)].append(data)
    out: dict[str, int] = collections.Counter()
    for (topic, _), items in groups.items():
        out[topic] += len(zstandard.compress(b"".join(items)))
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))
