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
