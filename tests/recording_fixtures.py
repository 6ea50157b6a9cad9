"""Test fixture: write a synthetic walkcap recording with every topic, fast.

Frames come from devices.simulator.synthetic.synthetic_frame (a ray-cast step scene with 1 % range
noise), a few of them re-stamped; times are synthetic session-clock times starting at T0.
"""

from __future__ import annotations

import dataclasses
import errno
import functools
import os
from pathlib import Path

import numpy as np

from capture.recording.chunks import TrackedFile
from capture.recording.writer import Recorder
from devices.base import DeviceEvent
from devices.frames import MODES, ImuSample
from devices.simulator.synthetic import synthetic_frame

T0 = 1_000_000_000_000  # 1000 s on the session clock
FPS = 45.0
IMU_HZ = 100.0
METADATA = {
    "session": {
        "subject": "S07",
        "height_m": "1.78",
        "amputee": "True",
        "side": "left",
        "condition": "indoor",
        "trial": "3",
        "notes": "test",
    },
    "devices": {"camera_backend": "mock", "imu_backend": "mock"},
    "software": {"walkcap_version": "0.1.0", "model_hash": "abc123"},
}
ATTACHMENTS = {"walkcap.toml": b"[camera]\nfps = 45.0\n", "model.json": b'{"hash": "abc123"}'}


@functools.cache
def _frames(n: int = 12):
    return tuple(synthetic_frame(i, 0) for i in range(n))


def frame_at(index: int):
    base = _frames()[index % len(_frames())]
    t = frame_time(index)
    return dataclasses.replace(
        base,
        index=index,
        device_time_ns=t,
        host_time_ns=t + 3_000_000,
        truth={"mode": truth_mode(index), "pose": np.eye(4)},
    )


def frame_time(index: int) -> int:
    return T0 + int(round(index * 1e9 / FPS))


def truth_mode(index: int) -> str:
    return MODES[(index // 40) % len(MODES)]


def probabilities(index: int) -> np.ndarray:
    p = np.full(len(MODES), 0.05)
    p[(index // 40) % len(MODES)] = 0.8
    return p


def imu_sample(k: int) -> ImuSample:
    t = T0 + int(round(k * 1e9 / IMU_HZ))
    return ImuSample(
        host_time_ns=t + 1_000_000,
        time_ns=t,
        packet_counter=k % 65536,
        sample_time_fine=k * 100,
        quaternion=np.array([0.9, 0.1, -0.2, 0.3]) / np.linalg.norm([0.9, 0.1, -0.2, 0.3]),
        acceleration=np.array([0.1, -0.2, 9.81]),
        rate_of_turn=np.array([0.01, 0.02, -0.03]),
        status_word=3,
        extra={"temperature": 31.5},
    )


def label_schedule(seconds: float) -> list[tuple[int, str, str]]:
    """A label change every 0.5 s (times between frames), cycling through the modes."""
    out = []
    k = 0
    while k * 0.5 < seconds:
        out.append((T0 + int(k * 0.5e9) + 7_000_000, MODES[k % len(MODES)], "operator"))
        k += 1
    return out


def write_recording(
    path: str | Path,
    seconds: float = 2.0,
    *,
    chunk_interval_s: float = 1.0,
    queue_size: int = 100_000,
    close: bool = True,
    gray: bool = False,
    zstd_level: int = 3,
) -> Recorder:
    """Every topic, in the order a session writes them; returns the (closed) recorder."""
    rec = Recorder(
        path,
        metadata=METADATA,
        attachments=ATTACHMENTS,
        queue_size=queue_size,
        cloud_voxel_m=0.0,  # exact clouds, to compare what comes back
        chunk_interval_s=chunk_interval_s,
        gray=gray,
        zstd_level=zstd_level,
    )
    rec.start()
    labels = label_schedule(seconds)
    n_frames = int(seconds * FPS)
    k_imu = 0
    for i in range(n_frames):
        t = frame_time(i)
        while T0 + k_imu * 1e9 / IMU_HZ <= t:
            rec.write_imu(imu_sample(k_imu))
            k_imu += 1
        while labels and labels[0][0] <= t:
            rec.write_label(*labels.pop(0))
        frame = frame_at(i)
        rec.write_frame(frame)
        cloud = np.column_stack(
            [np.linspace(0.0, 1.5, 300), np.zeros(300), np.full(300, -0.55) + 0.001 * i]
        )
        image = np.zeros((100, 100), np.uint8)
        image[50 + i % 20 :, :] = 1
        quaternion = None if i == 5 else np.array([np.cos(0.1), 0.0, np.sin(0.1), 0.0])
        rec.write_processed(
            i, t, frame.host_time_ns, cloud, image, quaternion, "" if i != 5 else "no orientation"
        )
        fused = (
            {}
            if i < 2
            else {
                "frame_index": i - 1,
                "decision": truth_mode(i - 1),
                "posterior": probabilities(i - 1),
                "voted": truth_mode(i - 2) if i > 2 else None,
                "voted_frame_index": i - 2 if i > 2 else None,
            }
        )
        rec.write_inference(i, t, frame.host_time_ns + 9_000_000, probabilities(i), fused)
        rec.write_features(i, t, {"riser_m": 0.17, "tread_m": float("nan"), "ok": True})
        rec.write_truth(i, t, frame.truth)
        if i == 10:
            rec.write_event(DeviceEvent(t, "imu", "gap", "3 samples missing", {"missing": 3}))
            rec.write_event(
                {"time_ns": t, "device": "operator", "kind": "marker", "message": "stairs start"}
            )
    if close:
        rec.close()
    return rec


def write_trial(
    path: str | Path,
    labels: list[tuple[int, str, str]],
    *,
    session: dict | None = None,
    frames: int = 90,
    metadata: dict | None = None,
    close: bool = True,
) -> Recorder:
    """A small trial: CNN outputs (the truth mode at 0.8), fused decisions and the given
    label changes, no images; fast to write and to read."""
    meta = {"session": session or {"subject": "S01", "condition": "indoor", "trial": 1}}
    meta.update(metadata or {})
    rec = Recorder(path, metadata=meta, queue_size=100_000)
    rec.start()
    pending = sorted(labels)
    for i in range(frames):
        t = frame_time(i)
        while pending and pending[0][0] <= t:
            rec.write_label(*pending.pop(0))
        write_decision(rec, i)
    for change in pending:
        rec.write_label(*change)
    if close:
        rec.close()
    return rec


def write_decision(rec: Recorder, index: int) -> None:
    """Frame `index`'s CNN output (the truth mode at 0.8) and its fused decision, 1 ms on."""
    t = frame_time(index)
    fused = {"frame_index": index, "decision": truth_mode(index), "posterior": probabilities(index)}
    rec.write_inference(index, t, t + 1_000_000, probabilities(index), fused)


def disk_full_after(budget: int):
    """A `TrackedFile.write` that raises ENOSPC past `budget` bytes, as a full disk does."""
    real = TrackedFile.write

    def write(file, data):
        if file.position + len(data) > budget:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(file, data)

    return write


def decoded_messages(path: str | os.PathLike, relative: bool = False) -> dict:
    """Every message of a recording decoded, per topic, in file order, for comparing two
    files by content; `relative`: times counted from the first IMU sample (a synthesized
    recording starts at the clock's time)."""
    from capture.recording import open_recording

    rec = open_recording(path)
    t0 = next(m.data["time_ns"] for m in rec.messages(["/imu"])) if relative else 0

    def plain(v):
        if isinstance(v, dict):
            return {
                k: x - t0 if k.endswith("time_ns") and isinstance(x, int) else plain(x)
                for k, x in v.items()
            }
        if isinstance(v, list):
            return [plain(x) for x in v]
        if isinstance(v, np.ndarray):
            return (v.dtype.str, v.shape, v.tobytes())
        return v

    out: dict = {}
    for m in rec.messages():
        out.setdefault(m.topic, []).append(
            (m.log_time_ns - t0, m.publish_time_ns - t0, m.sequence, plain(m.data))
        )
    return out


def synth_recording(tmp_path: Path, method: str, preset: str, frames: int) -> Path:
    """The one recording `walkcap synth --format recording` (seed 78) makes in `tmp_path`
    with [fusion] method = `method`."""
    from tui import cli

    config = tmp_path / "walkcap.toml"
    config.write_text(f'[fusion]\nmethod = "{method}"\n')
    out = tmp_path / "synth"
    args = ["--config", str(config), "synth", "--format", "recording", "--out", str(out)]
    args += ["--sessions", "1", "--preset", preset, "--seed", "78", "--frames", str(frames)]
    assert cli.main(args) == 0
    (path,) = out.glob("*.mcap")
    return path
