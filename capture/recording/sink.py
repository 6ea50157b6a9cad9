"""Where a session's data goes: the one interface of the recorder and the live taps.

A live session hands every sink the same calls: the raw data as it comes (frames, IMU
samples, device events, simulator truth and gait events), what the pipeline derives from each frame
(preprocessing, inference, terrain features) and the operator's labels and markers. The
Recorder writes them into the trial's file; a tap (LSL outlets, the Foxglove live view)
sends what it carries and inherits a no-op for the rest.

Every call runs on a session thread that must not wait: it returns at once (a queue, a
non-blocking send), keeps references to the arrays it is given (the caller never modifies
them) and never raises.
"""

from __future__ import annotations

import numpy as np


class Sink:
    """A receiver of the session's data; each write_* does nothing unless overridden."""

    def write_frame(self, frame, time_ns: int | None = None) -> None:
        """A DepthFrame; its publish time `time_ns` (None: the frame's device time)."""

    def write_imu(self, sample) -> None:
        """An ImuSample."""

    def write_processed(
        self,
        frame_index: int,
        time_ns: int,
        log_time_ns: int,
        cloud: np.ndarray,
        image: np.ndarray,
        quaternion,
        flag: str,
    ) -> None:
        """Leveled cloud, classifier input image, camera orientation (None: unknown) and
        the preprocessing flag of a frame."""

    def write_inference(
        self, frame_index: int, time_ns: int, log_time_ns: int, cnn_probs, fused: dict | None
    ) -> None:
        """CNN probabilities of a frame; `fused` (may be empty) refers to an earlier frame."""

    def write_features(self, frame_index: int, time_ns: int, features: dict) -> None:
        """Terrain features of a frame."""

    def write_truth(self, frame_index: int, time_ns: int, truth: dict) -> None:
        """The simulator's truth for a frame (mock sessions)."""

    def write_gait(self, event, log_time_ns: int | None = None) -> None:
        """A GaitEvent: the detector's (/gait) or the simulator's (/sim/gait); `log_time_ns`
        is when it was known (None: its own time)."""

    def write_label(self, time_ns: int, mode: str, source: str) -> None:
        """The operator's mode from `time_ns` on ('' = no mode)."""

    def write_event(self, event) -> None:
        """A DeviceEvent or a dict with its keys: device faults, gaps, operator markers."""
