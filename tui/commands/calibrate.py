"""`walkcap calibrate`: estimate the camera mounting from standing on level ground.

The subject stands still on open level floor, camera unobstructed, for a few seconds.
Every frame's floor plane, seen through the IMU's orientation at the frame's time, gives
the camera's roll and pitch relative to the IMU (inference.calibration). The command
prints old -> new and writes [mounting] to the configuration file; it refuses, writing
nothing, when the floor is not found or the subject moved.

On mock devices the simulated walker stands at the start of its course.
"""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path

import numpy as np

HELP = "estimate the camera mounting from standing on level ground"
MAX_FRAMES = 30  # evenly spread over the collection: plenty for a plane and a mean
MAX_IMU_GAP_S = 0.1  # a frame without an IMU sample this close gets no orientation
FIRST_FRAME_TIMEOUT_S = 5.0


def add_arguments(parser) -> None:
    parser.add_argument(
        "--seconds",
        type=float,
        default=3.0,
        metavar="S",
        help="how long to collect while the subject stands still (default 3)",
    )
    parser.add_argument(
        "--write",
        metavar="PATH",
        help="configuration file to write [mounting] to (default: the "
        "configuration read, else ./walkcap.toml)",
    )
    parser.add_argument(
        "--dry-run", action="store_true", help="estimate and show the result, write nothing"
    )
    parser.add_argument(
        "--json", action="store_true", help="print the result as JSON instead of the table"
    )


def run(args, config) -> int:
    from capture.live.devices import close_devices
    from inference.calibration import CalibrationError, estimate_mounting

    if not args.seconds > 0:
        raise CalibrationError(f"--seconds must be positive, got {args.seconds:g}")
    print(
        f"stand still on level ground, camera unobstructed: collecting {args.seconds:g} s ...",
        flush=True,
        file=sys.stderr if args.json else sys.stdout,  # stdout is the JSON's
    )
    camera, imu = open_devices(config)
    try:
        frames, quaternions = collect(camera, imu, args.seconds)
    finally:
        close_devices(camera, imu)

    m = config.mounting
    current = (m.roll_deg, m.pitch_deg, m.yaw_deg)
    result = estimate_mounting(
        [f.xyz for f in frames],
        [f.confidence for f in frames],
        quaternions,
        current,
        config.preprocess.min_confidence,
    )
    if args.json:
        return _json_result(args, config, result, current)
    print(
        f"frames: {result.frames_used} of {result.frames_total} show the floor; "
        f"floor inliers {100 * result.inlier_fraction:.0f}%, "
        f"plane RMS {1000 * result.plane_rms_m:.1f} mm, "
        f"camera height {result.camera_height_m:.3f} m"
    )
    if not result.ok:
        raise CalibrationError(f"calibration refused, nothing written: {result.problem}")
    print(f"fit residual {result.residual_deg:.2f} deg, thigh motion {result.motion_deg:.2f} deg")
    print(f"roll   {current[0]:+7.2f} -> {result.roll_deg:+7.2f} deg")
    print(f"pitch  {current[1]:+7.2f} -> {result.pitch_deg:+7.2f} deg")
    print(f"yaw    {current[2]:+7.2f}    (kept: not observable from a floor)")
    if args.dry_run:
        print("dry run: nothing written")
        return 0

    path = _write(args, config, result)
    print(f"wrote [mounting] to {path}")
    return 0


def _json_result(args, config, result, current) -> int:
    import dataclasses
    import json

    from capture.recording.topics import jsonable
    from inference.calibration import CalibrationError

    data = {k: v for k, v in dataclasses.asdict(result).items() if k != "per_frame"}
    data["ok"] = result.ok
    data["current"] = {"roll_deg": current[0], "pitch_deg": current[1], "yaw_deg": current[2]}
    data["written"] = None
    if result.ok and not args.dry_run:
        data["written"] = str(_write(args, config, result))
    print(json.dumps(jsonable(data), indent=2))
    if not result.ok:
        raise CalibrationError(f"calibration refused, nothing written: {result.problem}")
    return 0


def _write(args, config, result) -> Path:
    """[mounting] into the configuration file; returns its path."""
    from capture import config as config_mod

    path = Path(args.write or config.source or config_mod.DEFAULT_PATH)
    # Another existing file keeps its own settings; only [mounting] changes there.
    same_file = bool(config.source) and path.resolve() == Path(config.source).resolve()
    target = config_mod.load(path) if path.exists() and not same_file else config
    target.mounting.roll_deg = round(result.roll_deg, 2)
    target.mounting.pitch_deg = round(result.pitch_deg, 2)
    config_mod.save(target, path)
    return path


def open_devices(config):
    """The configured camera and IMU, opened as a session opens them; a mock walker stands."""
    import copy

    from capture.live.devices import open_devices as open_session_devices

    if config.camera.backend == "mock":
        config = copy.deepcopy(config)  # standing is for this run, never saved
        config.simulator.stand = True
    return open_session_devices(config)


def collect(camera, imu, seconds: float) -> tuple[list, list[np.ndarray]]:
    """Frames for `seconds` and the IMU orientation at each frame's time (NaN if none)."""
    from capture.live.pipeline import OrientationTrack
    from devices.errors import DeviceOperationError

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
