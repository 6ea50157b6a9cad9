"""Replay: the pipeline run again on a recording's depth and IMU, into a new recording.

Deterministic and single-threaded: frames in order, each with the IMU samples recorded
up to just after its time in the orientation track, exactly as the live session would
have had them. The original file is only read.
"""
from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from capture import topics as T
from capture.errors import CaptureError
from capture.pipeline import CNN_THREADS, OrientationTrack, Pipeline, model_hash, record_result
from devices.frames import ImuSample

IMU_LOOKAHEAD_NS = 20_000_000  # samples recorded up to this long after a frame may be used


@dataclass
class ReplayReport:
    source: str
    output: str
    frames: int
    seconds_recorded: float
    seconds_taken: float
    stats: object  # RecorderStats of the new file

    @property
    def speedup(self) -> float:
        return self.seconds_recorded / self.seconds_taken if self.seconds_taken > 0 else float("inf")


def _imu_sample(d: dict) -> ImuSample:
    def arr(key):
        v = d.get(key)
        return None if v is None else np.asarray(v, dtype=np.float64)

    return ImuSample(host_time_ns=int(d["host_time_ns"]), time_ns=d.get("time_ns"),
                     packet_counter=d.get("packet_counter"),
                     sample_time_fine=d.get("sample_time_fine"), quaternion=arr("quaternion"),
                     acceleration=arr("acceleration"), rate_of_turn=arr("rate_of_turn"),
                     status_word=d.get("status_word"), extra=d.get("extra") or {})


def default_output(source: Path, folder: Path | None = None) -> Path:
    folder = folder or source.parent
    stem = source.stem
    k = 1
    while True:
        out = folder / f"{stem}.replay{'' if k == 1 else k}.mcap"
        if not out.exists():
            return out
        k += 1


def replay(source: str | Path, config, *, output: str | Path | None = None, speed: float | None = None,
           classifier=None, progress=None) -> ReplayReport:
    """Run the pipeline on `source` into `output`. speed None: as fast as possible;
    else paced at `speed` x the recorded rate."""
    from capture.reader import depth_frames, open_recording
    from capture.recorder import Recorder
    from inference.fusion import make_fusion
    from inference.model import load_classifier
    from inference.preprocess import PreprocessParams

    source = Path(source)
    rec = open_recording(source)
    if T.DEPTH not in rec.topics:
        raise CaptureError(f"{source}: no depth frames to replay")
    output = Path(output) if output else default_output(source)
    if output.resolve() == source.resolve():
        raise CaptureError("the replay must go to a new file; the original is never modified")
    classifier = classifier or load_classifier(config.model.path or None, threads=CNN_THREADS)
    cfg = config.fusion
    fusion = make_fusion("hmm+voting", window=cfg.window, vote_delay=cfg.vote_delay,
                         transition=np.asarray(cfg.transition))
    pipeline = Pipeline(PreprocessParams.from_config(config), classifier, fusion)

    imu = [_imu_sample(m.data) for m in rec.messages([T.IMU])]
    imu.sort(key=lambda s: s.time_ns if s.time_ns is not None else s.host_time_ns)
    labels = [m.data for m in rec.messages([T.LABELS])]
    events = [m.data for m in rec.messages([T.EVENTS])]

    metadata = {name: dict(values) for name, values in rec.metadata.items()
                if name in ("session", "devices", "camera")}
    software = dict(rec.metadata.get("software", {}))
    software.update({
        "replay_of": source.name,
        "model_path": config.model.path or "bundled",
        "model_hash": model_hash(classifier),
        "fusion_window": str(cfg.window), "fusion_vote_delay": str(cfg.vote_delay),
        "fusion_transition": json.dumps(cfg.transition),
        "preprocess": json.dumps(pipeline.params.to_dict()),
    })
    metadata["software"] = software
    attachments = {name: data for name, data in rec.attachments.items()}
    recorder = Recorder(output, metadata=metadata, attachments=attachments, blocking=True)
    recorder.start()
    track = OrientationTrack(span_s=5.0)
    i_imu = 0
    frames = 0
    first_t = last_t = None
    wall0 = time.monotonic()
    try:
        for lab in labels:
            recorder.write_label(int(lab["time_ns"]), lab.get("mode", ""), lab.get("source", ""))
        for ev in events:
            recorder.write_event(dict(ev))
        for frame in depth_frames(source):
            t = frame.device_time_ns
            first_t = t if first_t is None else first_t
            last_t = t
            if speed:  # recorded pace, scaled
                wait = (t - first_t) * 1e-9 / speed - (time.monotonic() - wall0)
                if wait > 0:
                    time.sleep(wait)
            while i_imu < len(imu):
                s = imu[i_imu]
                ts = s.time_ns if s.time_ns is not None else s.host_time_ns
                if ts > t + IMU_LOOKAHEAD_NS:
                    break
                if s.quaternion is not None:
                    track.add(ts, s.quaternion, s.rate_of_turn)
                recorder.write_imu(s)
                i_imu += 1
            q, _ = track.at(t)
            record_result(recorder, frame, pipeline.process(frame, q, t), frame.host_time_ns)
            frames += 1
            if progress is not None:
                progress(frames)
        for s in imu[i_imu:]:
            recorder.write_imu(s)
    finally:
        stats = recorder.close()
    taken = time.monotonic() - wall0
    recorded = (last_t - first_t) * 1e-9 if frames > 1 else 0.0
    return ReplayReport(str(source), str(output), frames, recorded, taken, stats)
