"""`replay` camera backend: the depth frames of a walkcap recording, played back.

The recording is `camera_id` in the configuration (or `path=`). Frames come at the recorded
pace times `speed`, or as fast as the consumer takes them when `realtime` is false; they
are re-stamped onto the session clock (recorded spacing kept), with their recorded truth.
The recording's own IMU samples are available as `recorded_imu()` for offline use.
It reads recordings, so it lives with the reader; capture registers it in devices' camera
registry under the name "replay".
"""

from __future__ import annotations

import logging
from pathlib import Path

from capture.errors import CaptureError
from capture.recording import topics as T
from capture.recording.reader import depth_frames, imu_sample, open_recording
from devices import clock
from devices.base import OK, Producer
from devices.camera import Camera
from devices.clock import now_ns
from devices.errors import DeviceNotAvailable

log = logging.getLogger(__name__)


class ReplayCamera(Camera):
    backend = "replay"

    def __init__(
        self,
        config=None,
        *,
        path: str | None = None,
        speed: float = 1.0,
        realtime: bool = True,
        loop: bool = False,
    ) -> None:
        super().__init__(config)
        self.path = Path(path or getattr(self.config, "camera_id", "") or "")
        self.speed = speed
        self.realtime = realtime
        self.loop = loop
        self._producer = Producer("walkcap-replay-camera", self._run)
        self._halt = self._producer.halt

    @classmethod
    def from_config(cls, camera_config, simulator_config=None, **kw) -> ReplayCamera:
        if simulator_config is not None and "realtime" not in kw:
            kw["realtime"] = simulator_config.realtime
        return cls(camera_config, **kw)

    def _open(self) -> None:
        if not str(self.path) or not self.path.is_file():
            raise DeviceNotAvailable(
                f"replay camera: no recording at {str(self.path) or '(none)'}; "
                "set [camera] camera_id to a .mcap file"
            )
        try:
            rec = open_recording(self.path)
        except CaptureError as e:
            raise DeviceNotAvailable(f"replay camera: {e}") from None
        self.geometry = rec.geometry()
        self.details = {"recording": str(self.path), "speed": self.speed}

    def _start(self) -> None:
        self._producer.start()

    def _stop(self) -> None:
        self._producer.stop()

    def _run(self) -> None:
        try:
            while not self._halt.is_set():
                self._play_once()
                if not self.loop:
                    self._finish("end_of_recording", f"end of {self.path.name}")
                    return
        except Exception as e:  # a cut-off or corrupt file ends playback, never the session
            log.exception("replay camera")
            self._fail(f"replay stopped: {type(e).__name__}: {e}")

    def _play_once(self) -> None:
        start = now_ns()
        first = None
        for frame in depth_frames(self.path):
            if self._halt.is_set():
                return
            first = frame.device_time_ns if first is None else first
            due = start + int((frame.device_time_ns - first) / self.speed)
            if self.realtime:
                wait = clock.seconds(due - now_ns())
                if wait > 0 and self._halt.wait(wait):
                    return
            else:  # as fast as the consumer takes them, never dropping
                while len(self._buffer) >= self._buffer._maxlen - 1 and not self._halt.is_set():
                    self._halt.wait(0.002)
            frame.device_time_ns = due
            frame.host_time_ns = now_ns()
            self._set_state(OK, "playing")
            self._deliver(frame)

    def recorded_imu(self):
        """The recording's IMU samples (ImuSample), in time order, on the recorded clock."""
        return [imu_sample(m.data) for m in open_recording(self.path).messages([T.IMU])]
