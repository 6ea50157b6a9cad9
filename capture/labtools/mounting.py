"""The camera mounting from standing on level ground (`walkcap calibrate`).

The subject stands still on open level floor, camera unobstructed, for a few seconds.
Every frame's floor plane, seen through the IMU's orientation at the frame's time, gives
the camera's roll and pitch relative to the IMU (inference.calibration). `calibrate`
collects and estimates; `write_mounting` puts the result into a configuration file.

On mock devices the simulated walker stands at the start of its course.
"""

from __future__ import annotations

import copy
import threading
import time
from pathlib import Path

import numpy as np

from capture import config as config_mod
from capture.config import Config
from capture.live.devices import close_devices
from capture.live.devices import open_devices as open_session_devices
from capture.live.pipeline import OrientationTrack
from devices.errors import DeviceOperationError
from inference.calibration import CalibrationResult, estimate_mounting

MAX_FRAMES = 30  # evenly spread over the collection: plenty for a plane and a mean
MAX_IMU_GAP_S = 0.1  # a frame without an IMU sample this close gets no orientation
FIRST_FRAME_TIMEOUT_S = 5.0


def open_devices(config: Config):
    """The configured camera and IMU, opened as a session opens them; a mock walker stands."""
    if config.camera.backend == "mock":
        config = copy.deepcopy(config)  # standing is for this run, never saved
        config.simulator.stand = True
    return open_session_devices(config)


def current_mounting(config: Config) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in degrees, as the configuration has them."""
    m = config.mounting
    return (m.roll_deg, m.pitch_deg, m.yaw_deg)


def calibrate(config: Config, seconds: float) -> CalibrationResult:
    """The mounting estimated from `seconds` of the configured devices, opened and closed
    here; the result says whether it is to be trusted (`ok`, `problem`)."""
    camera, imu = open_devices(config)
    try:
        frames, quaternions = collect(camera, imu, seconds)
    finally:
        close_devices(camera, imu)
    return estimate_mounting(
        [f.xyz for f in frames],
        [f.confidence for f in frames],
        quaternions,
        current_mounting(config),
        config.preprocess.min_confidence,
    )


def collect(camera, imu, seconds: float) -> tuple[list, list[np.ndarray]]:
    """Frames for `seconds` and the IMU orientation at each frame's time (NaN if none)."""
    track = OrientationTrack(span_s=seconds + 10.0)
    halt = threading.Event()

    def imu_loop() -> None:
        while not halt.is_set():
            sample = imu.recv(0.05)
            if sample is not None and sample.quaternion is not None:
                t = sample.time_ns if sample.time_ns is not None else sample.host_time_ns
                track.add(t, sample.quaternion)

    thread = threading.Thread(target=imu_loop, name="walkcap-calibrate-imu", daemon=True)
    frames = []
    try:
        imu.start()
        thread.start()
        camera.start()
        start = time.monotonic()
        while True:
            now = time.monotonic() - start
            if now >= seconds and frames:
                break
            if now >= seconds + FIRST_FRAME_TIMEOUT_S:
                raise DeviceOperationError(f"no frames from the camera in {now:.0f} s")
            frame = camera.recv(0.1)
            if frame is not None:
                frames.append(frame)
        track.wait_until(frames[-1].device_time_ns, 1.0)  # the IMU catches up
    finally:
        halt.set()
        if thread.is_alive():
            thread.join(timeout=1.0)
    step = max(1, len(frames) // MAX_FRAMES)
    frames = frames[::step][:MAX_FRAMES]
    quaternions = []
    for frame in frames:
        q, gap_ns = track.at(frame.device_time_ns)
        ok = q is not None and gap_ns <= MAX_IMU_GAP_S * 1e9
        quaternions.append(np.asarray(q, dtype=np.float64) if ok else np.full(4, np.nan))
    if not any(np.all(np.isfinite(q)) for q in quaternions):
        raise DeviceOperationError("no orientation from the IMU at the frames' times")
    return frames, quaternions


def write_mounting(config: Config, result: CalibrationResult, path: str | None = None) -> Path:
    """[mounting] into the configuration file `path` (default: the configuration read, else
    ./walkcap.toml); returns its path."""
    path = Path(path or config.source or config_mod.DEFAULT_PATH)
    # Another existing file keeps its own settings; only [mounting] changes there.
    same_file = bool(config.source) and path.resolve() == Path(config.source).resolve()
    target = config_mod.load(path) if path.exists() and not same_file else config
    target.mounting.roll_deg = round(result.roll_deg, 2)
    target.mounting.pitch_deg = round(result.pitch_deg, 2)
    config_mod.save(target, path)
    return path
