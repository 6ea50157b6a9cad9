"""A stand-in for capture.live.session.Session for the UI tests: same public surface,
deterministic snapshots built from the real dataclasses, and a record of every command."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np

from capture.errors import CaptureError
from capture.live.pipeline import FrameResult
from capture.live.session import Snapshot
from capture.live.timeline import TimelineEntry
from capture.live.trials import SubjectInfo
from capture.recording.labels import LabelChange
from capture.recording.writer import RecorderState, RecorderStats
from devices.base import DeviceEvent, DeviceState, DeviceStatus
from devices.clock import now_ns
from devices.frames import MODES
from inference.fusion import FusionOutput

NOW_NS = 100_000_000_000  # the snapshot's clock: fixed, so screenshots are stable
FPS = 15


def stairs_profile() -> np.ndarray:
    """Four 0.16 m risers with 0.30 m treads, first riser 0.2 m ahead: (forward, height)."""
    xs = np.arange(0.0, 1.5, 0.01)
    steps = np.clip(np.floor((xs - 0.2) / 0.30) + 1, 0, 4)
    heights = steps * 0.16
    risers = [
        (0.2 + 0.3 * k, h) for k in range(4) for h in np.arange(0.16 * k, 0.16 * (k + 1), 0.01)
    ]
    return np.vstack([np.column_stack([xs, heights]), np.array(risers)]).astype(np.float32)


def image_from_profile(profile: np.ndarray) -> np.ndarray:
    """The 100 x 100 binary image as inference.preprocess makes it.

    Row 0 is the highest, column 0 the nearest.
    """
    img = np.zeros((100, 100), dtype=np.uint8)
    p = profile - profile.min(axis=0) + 0.01
    cols, rows = (p[:, 0] / 0.01).astype(int), (p[:, 1] / 0.01).astype(int)
    keep = (cols < 100) & (rows < 100)
    img[99 - rows[keep], cols[keep]] = 1
    return img


def timeline(now_ns: int = NOW_NS, seconds: float = 20.0) -> list[TimelineEntry]:
    """Level ground, then up stairs 10 s ago; the CNN slips now and then, fusion lags a frame."""
    n = int(seconds * FPS)
    entries = []
    for i in range(n):
        t = now_ns - int((n - 1 - i) * 1e9 / FPS)
        true = 0 if i < n // 2 else 1
        cnn = true if i % 37 not in (5, 6) else 3
        if i in range(n // 2 - 4, n // 2):  # the camera sees the stairs before the operator
            cnn = 1
        fused = 0 if i < n // 2 - 2 else 1
        entries.append(
            TimelineEntry(
                index=1000 + i,
                time_ns=t,
                label=MODES[true],
                cnn=cnn,
                fused=fused if i < n - 1 else None,
                voted=None,
                truth=None,
            )
        )
    return entries


def _running(rate_hz: float, measured_hz: float, delivered: int, **more) -> DeviceStatus:
    """A mock device that runs as it should."""
    return DeviceStatus(
        "mock",
        DeviceState.OK,
        configured_rate_hz=rate_hz,
        measured_rate_hz=measured_hz,
        delivered=delivered,
        **more,
    )


class FakeSession:
    def __init__(
        self,
        *,
        start_error: Exception | None = None,
        start_gate: threading.Event | None = None,
        recordings: Path | None = None,
    ) -> None:
        self.start_error = start_error
        self.start_gate = start_gate  # start() waits for it, like devices being opened
        self.recordings = recordings or Path("recordings")
        self.fusion_method = "hmm+voting"  # the live default
        self.started = threading.Event()
        self.stopped = 0
        self.labels: list[LabelChange] = []
        self.undos = 0
        self.markers: list[tuple[int, str]] = []
        self.recordings_started: list[SubjectInfo] = []
        self.recordings_stopped = 0
        self.snapshots = 0
        self._label: str | None = "US"
        self._recording_path: Path | None = None
        self.trial_notice = ""
        self.trial: SubjectInfo | None = None
        self.alarms = None
        self.recorder_state, self.recorder_message = RecorderState.RECORDING, ""
        self.camera = _running(15.0, 14.9, 4500)
        self.imu = _running(
            100.0,
            99.8,
            30000,
            errors=2,
            details={"clock_offset_ms": 1.25, "drift_ppm": 48.0, "checksum_errors": 2},
        )
        self.events: list[DeviceEvent] = []
        self.timeline = timeline()
        profile = stairs_profile()
        self.latest = FrameResult(
            index=1299,
            time_ns=NOW_NS,
            host_time_ns=NOW_NS,
            orientation=np.array([1.0, 0, 0, 0]),
            image=image_from_profile(profile),
            cloud=np.zeros((0, 3), np.float32),
            profile=profile,
            flag="",
            probabilities=np.array([0.05, 0.82, 0.03, 0.07, 0.03]),
            cnn_decision=1,
            fused=FusionOutput(
                frame=1298,
                decision=1,
                posterior_frame=1299,
                probabilities=(0.02, 0.9, 0.02, 0.04, 0.02),
                voted=1,
                voted_frame=1297,
            ),
            features={
                "kind": "stairs",
                "direction": "up",
                "steps": 3,
                "riser_m": 0.162,
                "tread_m": 0.305,
                "slope_deg": None,
                "inlier_fraction": 0.93,
                "residual_m": 0.004,
            },
            done_ns=NOW_NS + 12_000_000,
        )

    # ---- life cycle
    def start(self) -> None:
        if self.start_gate is not None:
            self.start_gate.wait(10)
        if self.start_error is not None:
            raise self.start_error
        self.started.set()

    def stop(self):
        self.stopped += 1
        return self.stop_recording() if self._recording_path is not None else None

    # ---- commands
    def set_label(
        self, mode: str, source: str = "operator", time_ns: int | None = None
    ) -> LabelChange:
        if mode not in MODES:
            raise CaptureError(f"unknown mode {mode!r}")
        change = LabelChange(now_ns() if time_ns is None else time_ns, mode, source)
        self.labels.append(change)
        self._label = mode
        return change

    def undo_label(self) -> LabelChange | None:
        self.undos += 1
        if not self.labels:
            return None
        self.labels.pop()
        self._label = self.labels[-1].mode if self.labels else None
        return LabelChange(now_ns(), self._label or "", "undo")

    def add_marker(self, note: str = "", time_ns: int | None = None) -> None:
        self.markers.append((now_ns() if time_ns is None else time_ns, note))

    @property
    def label(self) -> str | None:
        return self._label

    @property
    def recording(self) -> bool:
        return self._recording_path is not None

    def start_recording(self, info: SubjectInfo, folder: str | Path | None = None) -> Path:
        info.validate()
        if self._recording_path is not None:
            raise CaptureError("already recording")
        self.recordings_started.append(info)
        folder = self.recordings if folder is None else Path(folder)
        self._recording_path = folder / f"{info.subject}_{info.condition}_t{info.trial:02d}.mcap"
        return self._recording_path

    def stop_recording(self):
        if self._recording_path is None:
            return None
        path, self._recording_path = self._recording_path, None
        self.recordings_stopped += 1
        return RecorderStats(
            path=str(path), state=RecorderState.STOPPED, bytes_written=12_345_678, messages=4321
        )

    def inject(self, device: str, fault: str, **kw) -> None:
        raise CaptureError("faults can be injected into mock devices only")

    # ---- what the UI reads
    def snapshot(self) -> Snapshot:
        self.snapshots += 1
        recording = None
        started = None
        if self._recording_path is not None:
            recording = RecorderStats(
                path=str(self._recording_path),
                state=self.recorder_state,
                message=self.recorder_message,
                bytes_written=3_456_789,
                messages=2100,
                queue_depth=3,
                queue_size=2048,
            )
            started = NOW_NS - 75_000_000_000
        return Snapshot(
            time_ns=NOW_NS,
            running=True,
            camera=self.camera,
            imu=self.imu,
            sync={"p50_ms": 0.4, "p99_ms": 1.9},
            label=self._label,
            latest=self.latest,
            timeline=list(self.timeline),
            events=list(self.events),
            recording=recording,
            recording_started_ns=started,
            frames=1300,
            latency_ms={"p50": 11.8, "p99": 21.3},
            fusion_method=self.fusion_method,
        )
