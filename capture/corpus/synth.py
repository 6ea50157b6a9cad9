"""Simulated sessions written as recordings, as fast as the pipeline runs.

Offline and deterministic for a seed: the terrain-walk simulator renders every frame, the
IMU samples are the walker's thigh orientation at the IMU rate with sensor noise (no pty:
there is no real time to keep), the pipeline runs as live, the labels key the walker's
locomotion mode as an operator keys it (the `locomotion` reference; `/sim/truth` carries
what each image shows, the `terrain` reference), and a blocking recorder loses nothing.
The file has the same topics as a live recording, so eval, train and replay read both alike.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np

from capture import config as config_mod
from capture.corpus.dataset import SynthSettings, session_walker
from capture.live.pipeline import (
    OrientationTrack,
    build_pipeline,
    record_result,
    software_metadata,
)
from capture.recording.metadata import SessionRecord, devices_record
from devices import clock
from devices.clock import now_ns
from devices.frames import ImuSample
from devices.orientation_error import OrientationError, OrientationErrorModel
from devices.rotations import quat_conjugate, quat_multiply, quat_to_matrix
from inference.gait import GaitDetector

GRAVITY = np.array([0.0, 0.0, 9.81])
TRANSPORT_NS = 3_000_000  # a USB-serial hop: samples arrive ~3 ms after they are taken
FRAME_TRANSFER_NS = 5_000_000  # a ToF frame arrives ~5 ms after its exposure
MOUNTING_ERROR_DEG = SynthSettings.mounting_error_deg  # as a training session's


def imu_samples(
    simulator,
    rate_hz: float,
    rng: np.random.Generator,
    t0_ns: int,
    error_model: OrientationErrorModel | None = None,
):
    """The thigh's IMU at `rate_hz`: orientation with the attitude filter's slowly drifting
    error (devices.orientation_error, the MTi 1-series' accuracy), gravity, rate of turn."""
    error = OrientationError(error_model or OrientationErrorModel(), rng)
    n = int(simulator.duration_s * rate_hz) + 1
    t = np.arange(n) / rate_hz
    quats = np.asarray(simulator.thigh_quaternion(t), dtype=np.float64)
    for k in range(n):
        q = quats[k]
        noisy = error.apply(q, float(t[k]))
        accel = quat_to_matrix(q).T @ GRAVITY + rng.normal(0, 0.05, 3)
        nxt = quats[min(k + 1, n - 1)]
        dq = quat_multiply(quat_conjugate(q), nxt)  # body-frame rotation to the next sample
        gyro = 2 * dq[1:] * rate_hz * np.sign(dq[0] or 1.0) + rng.normal(0, 0.01, 3)
        time_ns = t0_ns + clock.to_ns(t[k])
        yield ImuSample(
            host_time_ns=time_ns + TRANSPORT_NS,
            time_ns=time_ns,
            packet_counter=k % 65536,
            sample_time_fine=int(t[k] * 1e4) % 2**32,
            quaternion=noisy,
            acceleration=accel,
            rate_of_turn=gyro,
            status_word=0b11,
        )


def synth_recording(
    path: str | Path,
    config: config_mod.Config,
    classifier,
    *,
    preset: str,
    seed: int,
    subject: str = "SIM01",  # a simulated subject, an id of the default subject_pattern
    trial: int = 1,
    max_frames: int = 0,
    vary_walker: bool = True,
    progress=None,
):
    """Walk one simulated course into the recording at `path`; returns its RecorderStats.

    `vary_walker`: the session's own walker and the mounting calibrated for it, drawn for
    the seed as a training session's (capture.corpus.dataset.session_walker); else the
    configured [simulator] walker and [mounting]."""
    from capture.recording.writer import Recorder
    from devices.simulator import Simulator

    cfg = copy.deepcopy(config)
    cfg.simulator.course, cfg.simulator.seed = preset, seed
    if vary_walker:
        walker, pitch, _ = session_walker(seed, True, cfg.simulator, MOUNTING_ERROR_DEG)
        for key, value in walker.items():
            setattr(cfg.simulator, key, value)
        cfg.mounting.pitch_deg = pitch
    simulator = Simulator.from_config(cfg.simulator, fps=cfg.camera.fps)
    rng = np.random.default_rng([seed, 4242])
    pipeline = build_pipeline(cfg, classifier)
    metadata = {
        "session": SessionRecord.build(
            subject=subject,
            condition=preset,
            trial=trial,
            notes=f"simulated: preset {preset}, seed {seed}",
        ).to_dict(),
        "devices": devices_record(cfg, simulated=True).to_dict(),
        "software": software_metadata(cfg, pipeline),
    }
    recorder = Recorder(
        path,
        metadata=metadata,
        blocking=True,
        attachments={"walkcap.toml": config_mod.dumps(cfg, secrets=False).encode()},
    )
    recorder.start()
    t0 = now_ns()
    track = OrientationTrack(span_s=5.0)
    imu = imu_samples(simulator, cfg.imu.rate_hz, rng, t0)
    pending = next(imu, None)
    n = int(simulator.duration_s * cfg.camera.fps)
    if max_frames:
        n = min(n, max_frames)
    mode = None
    detector = GaitDetector()
    walked_s = -1.0  # the walk's gait truth is written up to here (it starts at 0)
    try:
        for k in range(n):
            t = t0 + int(round(k / cfg.camera.fps * 1e9))
            while pending is not None and pending.time_ns <= t + TRANSPORT_NS:
                track.add(pending.time_ns, pending.quaternion, pending.rate_of_turn)
                recorder.write_imu(pending)
                for event in detector.push(pending):
                    recorder.write_gait(event, pending.host_time_ns)
                    pipeline.see_gait(event, pending.host_time_ns)  # as live
                pending = next(imu, None)
            frame = simulator.render(k / cfg.camera.fps, index=k)
            frame.device_time_ns, frame.host_time_ns = t, t + FRAME_TRANSFER_NS
            gait = simulator.gait_truth(walked_s, k / cfg.camera.fps, t)
            walked_s = k / cfg.camera.fps
            if gait and frame.truth is not None:
                frame.truth["gait"] = gait
            if frame.truth and frame.truth.get("locomotion_mode") != mode:
                mode = frame.truth["locomotion_mode"]
                recorder.write_label(t, mode, "simulator")
            q, age_ns = track.at(t)
            result = pipeline.process(frame, q, t, orientation_age_ns=age_ns)
            record_result(recorder, frame, result, frame.host_time_ns)
            if progress is not None:
                progress(1)
    finally:
        stats = recorder.close()
    return stats


_classifiers: dict = {}  # per process: a job's worker loads the model once for its tasks


def synth_recording_file(
    path: str | Path,
    config: config_mod.Config,
    preset: str,
    seed: int,
    trial: int,
    max_frames: int,
    vary_walker: bool = True,
) -> str:
    """synth_recording with the configured model, as one task of a corpus job
    (capture.corpus.jobs): the path written, or CaptureError when the recording failed."""
    from capture.errors import CaptureError
    from capture.live.pipeline import CNN_THREADS
    from inference.model import load_classifier

    key = config.model.path or ""
    if key not in _classifiers:
        _classifiers[key] = load_classifier(key or None, threads=CNN_THREADS)
    stats = synth_recording(
        path,
        config,
        _classifiers[key],
        preset=preset,
        seed=seed,
        trial=trial,
        max_frames=max_frames,
        vary_walker=vary_walker,
    )
    if stats.state == "failed":
        raise CaptureError(f"{path}: {stats.message}")
    return str(path)
