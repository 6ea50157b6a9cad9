import time

import pytest

from devices.camera import open_camera
from devices.config import CameraConfig
from devices.errors import DeviceNotAvailable
from tests.recording_fixtures import write_recording


def test_plays_the_recorded_frames_in_order(tmp_path):
    path = tmp_path / "r.mcap"
    write_recording(path)
    cfg = CameraConfig(backend="replay", camera_id=str(path), fps=15.0)
    camera = open_camera(cfg)
    camera.realtime = False
    camera.start()
    frames = []
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        f = camera.recv(0.5)
        if f is None and camera.status().state == "stopped":
            break
        if f is not None:
            frames.append(f)
    camera.close()
    assert frames, "no frames played"
    indices = [f.index for f in frames]
    assert indices == sorted(indices)
    times = [f.device_time_ns for f in frames]
    assert times == sorted(times)
    assert frames[0].xyz.shape == (frames[0].geometry.height, frames[0].geometry.width, 3)


def test_missing_recording_is_one_clear_error(tmp_path):
    cfg = CameraConfig(backend="replay", camera_id=str(tmp_path / "none.mcap"))
    with pytest.raises(DeviceNotAvailable, match="no recording"):
        open_camera(cfg)
