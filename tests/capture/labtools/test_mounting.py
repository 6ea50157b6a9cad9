"""The mounting from standing (capture.labtools.mounting): collected from the devices,
estimated, written into a configuration file."""

from types import SimpleNamespace

import numpy as np
import pytest

from capture import config as config_mod
from capture.config import Config
from capture.labtools import mounting
from tests.inference.test_calibration import standing


class FakeCamera:
    """Hands out pre-rendered frames stamped on the session clock, one per recv."""

    def __init__(self, xyz, conf):
        self.frames = list(zip(xyz, conf))
        self.k = 0
        self.calls: list[str] = []

    def start(self):
        self.calls.append("start")

    def recv(self, timeout=None):
        import time

        from devices.clock import now_ns
        from devices.frames import DepthFrame

        time.sleep(0.02)
        xyz, conf = self.frames[self.k % len(self.frames)]
        self.k += 1
        t = now_ns()
        return DepthFrame(self.k, t, t, xyz, conf, np.zeros(conf.shape, np.uint16))

    def stop(self):
        self.calls.append("stop")

    def close(self):
        self.calls.append("close")


class FakeImu(FakeCamera):
    """Samples of a standing thigh (quaternion at the time of each frame, in order)."""

    def __init__(self, quats):
        super().__init__([], [])
        self.quats = quats

    def recv(self, timeout=None):
        import time

        from devices.clock import now_ns
        from devices.frames import ImuSample

        time.sleep(0.005)
        self.k += 1
        t = now_ns()
        return ImuSample(host_time_ns=t, time_ns=t, quaternion=self.quats[self.k % 2])


def test_calibrate_collects_the_frames_with_their_orientation_and_closes_the_devices(
    monkeypatch,
):
    xyz, conf, quats = standing(count=2, sway_deg=0.0)
    camera, imu = FakeCamera(xyz, conf), FakeImu(quats)
    monkeypatch.setattr(mounting, "open_devices", lambda config: (camera, imu))
    config = Config()
    config.mounting.pitch_deg = 35.0
    result = mounting.calibrate(config, 0.3)
    assert result.ok, result.problem
    assert result.previous == (0.0, 35.0, 0.0)
    assert result.pitch_deg == pytest.approx(38.5, abs=0.1)
    assert 1 < result.frames_total <= mounting.MAX_FRAMES
    assert camera.calls == ["start", "stop", "close"] and imu.calls[-2:] == ["stop", "close"]


def test_write_mounting_changes_only_the_mounting_of_another_file(tmp_path):
    other = tmp_path / "rig.toml"
    other.write_text("[camera]\nfps = 30.0\n")
    config = Config()
    result = SimpleNamespace(roll_deg=1.234, pitch_deg=38.456)
    assert mounting.write_mounting(config, result, str(other)) == other
    saved = config_mod.load(other)
    assert (saved.mounting.roll_deg, saved.mounting.pitch_deg) == (1.23, 38.46)
    assert saved.camera.fps == 30.0
