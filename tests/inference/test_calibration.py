import json
import re

import numpy as np
import pytest

from devices.config import MountingConfig
from inference.calibration import CalibrationResult, estimate_mounting, floor_plane
from inference.config import PreprocessConfig
from inference.preprocess import preprocess
from tests import terrain_raycast as tr

TRUE_MOUNTING = (2.0, 38.5, 0.0)  # the camera sits 2 deg rolled, 3.5 deg lower than set


def standing(count=6, mounting=TRUE_MOUNTING, terrain=None, sway_deg=0.1, lean_deg=0.0, seed=0):
    """Frames of a subject standing on level ground; the thigh sways a little."""
    rng = np.random.default_rng(seed)
    xyz, conf, quats = [], [], []
    for k in range(count):
        q = tr.thigh_quaternion(
            1.5 + rng.normal(0, sway_deg) + lean_deg * k / max(count - 1, 1),
            -0.8 + rng.normal(0, sway_deg),
            40.0,
        )
        x, c = tr.render(
            terrain or tr.level(), q, mounting=mounting, noise_m=0.005, seed=seed * 10 + k
        )
        xyz.append(x)
        conf.append(c)
        quats.append(q)
    return xyz, conf, quats


def test_recovers_a_known_pitch_and_roll_offset():
    xyz, conf, quats = standing()
    result = estimate_mounting(xyz, conf, quats, current=(0.0, 35.0, 0.0))
    assert isinstance(result, CalibrationResult)
    assert result.ok, result.problem
    assert result.roll_deg == pytest.approx(2.0, abs=0.2)
    assert result.pitch_deg == pytest.approx(38.5, abs=0.2)
    assert result.yaw_deg == 0.0 and result.previous == (0.0, 35.0, 0.0)
    assert result.change_deg == pytest.approx((2.0, 3.5), abs=0.2)
    assert result.frames_used == result.frames_total == 6
    assert result.inlier_fraction > 0.9 and result.residual_deg < 0.3
    assert result.camera_height_m == pytest.approx(0.55, abs=0.01)
    # With the new mounting the floor levels flat.
    q = tr.thigh_quaternion(-10, 2, 0)
    x, c = tr.render(tr.level(), q, mounting=TRUE_MOUNTING)
    for mounting, flat in (((0.0, 35.0), False), ((result.roll_deg, result.pitch_deg), True)):
        fitted = MountingConfig(roll_deg=mounting[0], pitch_deg=mounting[1])
        z = preprocess(x, c, q, PreprocessConfig(), mounting=fitted).cloud[:, 2]
        assert (np.ptp(z) < 0.01) == flat


def test_keeps_the_mounting_yaw():
    xyz, conf, quats = standing(mounting=(-1.0, 30.0, 4.0), seed=2)
    result = estimate_mounting(xyz, conf, quats, current=(0.0, 35.0, 4.0))
    assert result.ok, result.problem
    assert result.roll_deg == pytest.approx(-1.0, abs=0.2)
    assert result.pitch_deg == pytest.approx(30.0, abs=0.2)
    assert result.yaw_deg == 4.0


def test_refuses_when_the_subject_moved():
    xyz, conf, quats = standing(lean_deg=8.0, seed=3)
    result = estimate_mounting(xyz, conf, quats, current=(0.0, 35.0, 0.0))
    assert not result.ok and "moved" in result.problem
    assert (result.roll_deg, result.pitch_deg) == (0.0, 35.0)


def test_refuses_without_a_floor():
    xyz, conf, quats = standing(count=4)
    blind = estimate_mounting(xyz, [np.zeros_like(c) for c in conf], quats, (0.0, 35.0, 0.0))
    assert not blind.ok and "floor was not found" in blind.problem
    # A wall 30 cm ahead fills the view: a plane, but not the floor.
    wall = standing(count=4, terrain=[(-5.0, 0.0), (0.3, 0.0), (0.3, 5.0)])
    walled = estimate_mounting(*wall, current=(0.0, 35.0, 0.0))
    assert not walled.ok and "floor was not found" in walled.problem
    assert all(f.get("rejected") == "no floor" for f in walled.per_frame)
    # No orientation from the IMU.
    nan = estimate_mounting(xyz, conf, [np.full(4, np.nan)] * 4, (0.0, 35.0, 0.0))
    assert not nan.ok and nan.frames_used == 0
    # Too few frames.
    assert not estimate_mounting(xyz[:2], conf[:2], quats[:2], (0.0, 35.0, 0.0)).ok
    assert not estimate_mounting([], [], [], (0.0, 35.0, 0.0)).ok


def test_floor_plane_height_and_normal():
    q = tr.thigh_quaternion(0, 0, 0)
    xyz, conf = tr.render(tr.level(), q, mounting=(0.0, 35.0, 0.0), height_m=0.6)
    normal, height, fraction, rms = floor_plane(xyz, conf)
    assert height == pytest.approx(0.6, abs=0.002) and fraction > 0.99 and rms < 0.002
    # Camera frame: y down, z forward; tilted 35 deg down, up is (0, -cos 35, -sin 35).
    np.testing.assert_allclose(
        normal, [0, -np.cos(np.radians(35)), -np.sin(np.radians(35))], atol=1e-3
    )
    assert floor_plane(xyz, np.zeros_like(conf)) is None


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


@pytest.fixture
def devices(monkeypatch):
    from tui.commands import calibrate

    def use(xyz, conf, quats):
        camera, imu = FakeCamera(xyz, conf), FakeImu(quats)
        monkeypatch.setattr(calibrate, "open_devices", lambda config: (camera, imu))
        return camera, imu

    return use


def test_calibrate_command_writes_the_mounting(devices, tmp_path, capsys):
    from capture import config as cfg
    from tui import cli

    xyz, conf, quats = standing(count=2, sway_deg=0.0)
    camera, imu = devices(xyz, conf, quats)
    path = tmp_path / "walkcap.toml"
    path.write_text("[camera]\nfps = 30.0\n[mounting]\npitch_deg = 35.0\n")
    assert cli.main(["--config", str(path), "calibrate", "--seconds", "0.3"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"pitch\s+\+35\.00 ->\s+\+38\.(49|50|51) deg", out), out
    assert "wrote [mounting]" in out
    saved = cfg.load(path)
    assert saved.mounting.pitch_deg == pytest.approx(38.5, abs=0.1)
    assert saved.mounting.roll_deg == pytest.approx(2.0, abs=0.1)
    assert saved.camera.fps == 30.0  # the rest of the file is kept
    assert camera.calls == ["start", "stop", "close"] and imu.calls[-2:] == ["stop", "close"]


def test_calibrate_command_refuses_when_the_subject_moves(devices, tmp_path, capsys):
    from tui import cli

    moving = [tr.thigh_quaternion(0, 0, 0), tr.thigh_quaternion(12, 0, 0)]
    frames = [tr.render(tr.level(), q, mounting=TRUE_MOUNTING) for q in moving]
    devices([f[0] for f in frames], [f[1] for f in frames], moving)
    path = tmp_path / "walkcap.toml"
    path.write_text("[mounting]\npitch_deg = 35.0\n")
    assert cli.main(["--config", str(path), "calibrate", "--seconds", "0.3"]) == 1
    err = capsys.readouterr().err
    assert "moved" in err and "nothing written" in err and len(err.strip().splitlines()) == 1
    assert path.read_text() == "[mounting]\npitch_deg = 35.0\n"


def test_calibrate_dry_run_and_write_elsewhere(devices, tmp_path, capsys):
    from capture import config as cfg
    from tui import cli

    devices(*standing(count=2, sway_deg=0.0))
    assert cli.main(["calibrate", "--seconds", "0.2", "--dry-run"]) == 0
    assert "nothing written" in capsys.readouterr().out
    assert not (tmp_path / "walkcap.toml").exists()
    other = tmp_path / "rig.toml"
    assert cli.main(["calibrate", "--seconds", "0.2", "--write", str(other)]) == 0
    assert cfg.load(other).mounting.pitch_deg == pytest.approx(38.5, abs=0.1)
    capsys.readouterr()
    devices(*standing(count=2, sway_deg=0.0))
    assert cli.main(["calibrate", "--seconds", "0.2", "--dry-run", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["ok"] and data["written"] is None
    assert data["pitch_deg"] == pytest.approx(38.5, abs=0.1)


def test_calibrate_on_mock_devices_recovers_the_simulated_mounting(tmp_path, capsys):
    """End to end: the mock walker stands, the IMU emulator feels its thigh, the floor
    gives back the simulator's camera tilt; the config file gets [mounting]."""
    from capture import config as config_mod
    from tui import cli

    path = tmp_path / "walkcap.toml"
    path.write_text("[mounting]\npitch_deg = 20.0\n[simulator]\ncamera_tilt_deg = 32.0\n")
    assert cli.main(["--config", str(path), "calibrate", "--seconds", "1.5"]) == 0
    written = config_mod.load(path)
    assert abs(written.mounting.pitch_deg - 32.0) < 1.0
    assert abs(written.mounting.roll_deg) < 1.0
    assert written.simulator.camera_tilt_deg == 32.0  # the rest of the file is kept
    assert not written.simulator.stand  # standing is for the calibration only


@pytest.mark.parametrize("tilt_deg", [20.0, 35.0])
def test_each_frame_s_floor_is_the_floor_under_range_noise_along_the_rays(tilt_deg):
    """A time-of-flight camera errs along its rays, by a share of the range (the pico
    flexx datasheet's figure at 15 fps, as the simulator renders it). The floor's plane of
    every frame is within a few hundredths of a degree and a millimetre of the truth: the
    noise along the rays does not tilt it, nor does the tilt of RANSAC's three-point
    plane, whose band of inliers one least-squares fit would keep tilted (up to 0.3 deg
    and 6 mm in a frame)."""
    from devices.frames import CameraGeometry
    from devices.simulator.render import datasheet_noise

    rays = CameraGeometry().rays().astype(np.float64)
    t = np.radians(tilt_deg)
    up = np.array([0.0, -np.cos(t), -np.sin(t)])  # camera frame: y down, z forward
    towards = -(rays @ up)
    rng_m = np.where(towards > 1e-3, 0.55 / np.maximum(towards, 1e-3), np.inf)
    rng = np.random.default_rng(48)
    for k in range(6):
        noisy = rng_m * (1.0 + datasheet_noise(15.0) * rng.standard_normal(rng_m.shape))
        seen = np.isfinite(noisy) & (noisy < 4.0)
        xyz = np.where(seen[..., None], rays * np.where(seen, noisy, 0.0)[..., None], 0.0)
        normal, height, _, _ = floor_plane(xyz.astype(np.float32), seen.astype(np.uint8), seed=k)
        assert height == pytest.approx(0.55, abs=0.002)
        # the tilt about the camera's x axis: the mounting's pitch
        pitch = np.degrees(np.arctan2(normal[2], -normal[1]) - np.arctan2(up[2], -up[1]))
        assert abs(pitch) < 0.1, (k, pitch)
