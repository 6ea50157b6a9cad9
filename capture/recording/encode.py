"""Walkcap data into the recording's messages, one `Encoded` record per message.

Pure functions of what they are given (capture.recording.topics builds each message), so any
thread or process runs them alike: the Recorder's writer thread, replay's reader process
(which hands the Recorder ready messages) and the Foxglove live tap.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capture.recording import topics as T

CLOUD_VOXEL_M = 0.02  # /camera/cloud: one point per voxel of this size (see thin_cloud)
CLOUD_MAX_POINTS = 4096


# Slotted, not frozen: built for every message on the writer thread, in a sixth of the time.
@dataclass(slots=True)
class Encoded:
    """One message ready for the file: its topic, its times on the session clock, its bytes."""

    topic: str
    log_time: int  # when the host received the data
    publish_time: int  # the data's own time (a frame's exposure, an IMU sample's time)
    data: bytes
    sequence: int = 0  # frame index on per-frame topics, packet counter on /imu


def message(topic: str, log_time: int, publish_time: int, *data, sequence: int = 0) -> Encoded:
    """The registered topic's message built from `data` (capture.recording.topics.TOPICS)."""
    return Encoded(topic, log_time, publish_time, T.TOPICS[topic].encode(*data), sequence)


def encode_depth(frame, t: int, log_time: int, gray: bool = False) -> list[Encoded]:
    """A DepthFrame's range and confidence (and amplitude, if `gray`), published at `t`."""
    depth = frame.range_mm  # a recording's own millimetres when replayed: exactly kept
    if depth is None:
        depth = T.range_mm(frame.xyz, frame.confidence)
    out = [
        message(T.DEPTH, log_time, t, depth, t, sequence=frame.index),
        message(T.CONFIDENCE, log_time, t, frame.confidence, t, sequence=frame.index),
    ]
    if gray and frame.gray is not None:
        out.append(message(T.GRAY, log_time, t, frame.gray, t, sequence=frame.index))
    return out


def thin_cloud(cloud, voxel_m: float = CLOUD_VOXEL_M, max_points: int = CLOUD_MAX_POINTS):
    """The cloud as recorded: one point per voxel, at most `max_points` (decimated evenly)."""
    points = np.asarray(cloud, dtype=np.float32).reshape(-1, 3)
    if voxel_m > 0 and len(points):
        # One point per 2 cm voxel: steps, ramps and curbs stay plain in Foxglove at about
        # a quarter of a 1 cm voxel's bytes, the difference between meeting the 2.5 MB/s
        # budget at 45 fps or not (`walkcap bench`). The cloud is derived data (depth,
        # /tf and the preprocessing parameters rebuild it); the depth is kept exactly.
        # (a voxel's key: its cells, each + 2^20, in 21 bits; numpy's float32 division)
        from inference.corridor import first_in_voxel

        points = points[first_in_voxel(np.ascontiguousarray(points), np.float32(voxel_m))]
    if len(points) > max_points:
        points = points[np.linspace(0, len(points) - 1, max_points).astype(int)]
    return points


def encode_processed(
    index: int,
    time_ns: int,
    log_time: int,
    cloud,
    image,
    quaternion,
    flag: str,
    voxel_m: float = CLOUD_VOXEL_M,
    max_points: int = CLOUD_MAX_POINTS,
) -> list[Encoded]:
    """A frame's preprocessing: cloud, classifier input, flag, and the orientation if known."""
    points = np.asarray(cloud, dtype=np.float32).reshape(-1, 3)
    kept = thin_cloud(points, voxel_m, max_points)
    return [encode_cloud(index, time_ns, log_time, kept)] + encode_preprocessing(
        index, time_ns, log_time, image, quaternion, flag, len(points), len(kept)
    )


def encode_cloud(index: int, time_ns: int, log_time: int, kept) -> Encoded:
    """A frame's cloud, thinned as recorded (thin_cloud)."""
    return message(T.CLOUD, log_time, time_ns, kept, time_ns, sequence=index)


def encode_preprocessing(
    index: int,
    time_ns: int,
    log_time: int,
    image,
    quaternion,
    flag: str,
    points: int,
    kept: int,
) -> list[Encoded]:
    """encode_processed without the cloud: the classifier input, the preprocessing record
    (the cloud's `points` and the `kept` of them recorded) and the orientation if known."""
    oriented = quaternion is not None and bool(np.all(np.isfinite(quaternion)))
    preprocess = (index, time_ns, flag, oriented, points, kept)
    out = [
        message(T.BINARY_IMAGE, log_time, time_ns, image, time_ns, sequence=index),
        message(T.PREPROCESS, log_time, time_ns, *preprocess, sequence=index),
    ]
    if oriented:
        out.append(message(T.TF, log_time, time_ns, quaternion, time_ns, sequence=index))
    return out


def encode_inference(
    index: int, time_ns: int, log_time: int, probabilities, fused: dict | None
) -> list[Encoded]:
    """The CNN's output for frame `index`, and the fusion's (if any) produced with it."""
    out = [message(T.CNN, log_time, time_ns, index, time_ns, probabilities, sequence=index)]
    if fused:
        out.append(message(T.FUSED, log_time, time_ns, index, time_ns, fused, sequence=index))
    return out


def encode_features(index: int, time_ns: int, log_time: int, features: dict) -> list[Encoded]:
    return [message(T.FEATURES, log_time, time_ns, index, time_ns, features, sequence=index)]


def encode_truth(index: int, time_ns: int, log_time: int, truth: dict) -> list[Encoded]:
    return [message(T.TRUTH, log_time, time_ns, index, time_ns, truth, sequence=index)]


def encode_gait(event, log_time: int | None = None) -> list[Encoded]:
    """A GaitEvent on its topic (/gait or /sim/gait), published at its time; logged when it
    was known (a detector knows an event a little after it happened)."""
    t = int(event.time_ns)
    return [message(T.gait_topic(event), t if log_time is None else log_time, t, event)]


def encode_imu(sample) -> list[Encoded]:
    """An ImuSample, published at its device-corrected time (its receipt when unknown)."""
    t = sample.time_ns if sample.time_ns is not None else sample.host_time_ns
    return [message(T.IMU, sample.host_time_ns, t, sample, sequence=sample.packet_counter or 0)]


def encode_label(time_ns: int, mode: str, source: str) -> list[Encoded]:
    return [message(T.LABELS, time_ns, time_ns, time_ns, mode, source)]


def encode_event(event) -> list[Encoded]:
    """A DeviceEvent or a dict with its keys, at the event's time (0 when a dict has none)."""
    entry = T.event_json(event)
    t = entry["time_ns"]
    return [Encoded(T.EVENTS, t, t, T.encode_json(entry))]
