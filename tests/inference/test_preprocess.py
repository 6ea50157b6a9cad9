import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from devices.config import MountingConfig
from devices.frames import DepthFrame
from inference.config import PreprocessConfig
from inference.preprocess import (
    Preprocessed,
    leveling_matrix,
    metadata,
    preprocess,
    preprocess_frame,
    rasterise,
)
from tests import terrain_raycast as tr

PARAMS = PreprocessConfig()
POSES = [(-20, 0, 0), (-10, 3, 40), (0, -4, -120), (10, 2, 170), (-5, 5, 75)]
BACKENDS = ["numpy", "open3d"]


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return np.logical_and(a, b).sum() / max(np.logical_or(a, b).sum(), 1)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("pose", POSES)
def test_level_ground_is_flat_at_camera_height(pose, backend):
    q = tr.thigh_quaternion(*pose)
    xyz, conf = tr.render(tr.level(), q, height_m=0.5, noise_m=0.005, seed=1)
    out = preprocess(xyz, conf, q, PreprocessConfig(backend=backend))
    assert out.ok, out.flag
    z = out.cloud[:, 2]
    assert abs(np.median(z) + 0.5) < 0.003
    assert np.percentile(np.abs(z + 0.5), 99) < 0.008  # flat: only the noise remains
    assert np.all(np.abs(out.cloud[:, 1]) <= 0.05 + 1e-6)
    assert out.cloud[:, 0].min() >= 0 and out.cloud[:, 0].max() <= 2.5 + 1e-6
    assert out.cloud.dtype == np.float32 and out.profile.dtype == np.float32
    np.testing.assert_array_equal(out.profile, out.cloud[:, [0, 2]])


def test_leveling_uses_the_mounting():
    q = tr.thigh_quaternion(-5, 0, 0)
    xyz, conf = tr.render(tr.level(), q, mounting=(0.0, 35.0, 0.0))
    wrong = preprocess(xyz, conf, q, PARAMS, mounting=MountingConfig(pitch_deg=30.0))
    x, z = wrong.cloud[:, 0], wrong.cloud[:, 2]
    slope = np.degrees(np.arctan(np.polyfit(x, z, 1)[0]))
    # Leveled with 5 degrees too little tilt, the floor seems to rise 5 degrees ahead.
    assert slope == pytest.approx(5.0, abs=0.3)
    right = preprocess(xyz, conf, q, PARAMS)
    assert np.ptp(right.cloud[:, 2]) < 1e-3


def test_image_is_the_authors_grid_with_the_documented_orientation():
    q = tr.thigh_quaternion(-10, 0, 0)
    xyz, conf = tr.render(tr.level(), q)
    out = preprocess(xyz, conf, q, PARAMS)
    assert out.image.shape == (100, 100) and out.image.dtype == np.uint8
    assert set(np.unique(out.image)) == {0, 1}
    # Flat ground: one row, one cell above the bottom (minimum shifted to 0.01 m), from
    # column 1 (nearest) to the last column kept (0.99 m of ground).
    rows, cols = np.nonzero(out.image)
    assert set(rows) == {98}
    assert cols.min() == 1 and cols.max() == 99
    assert out.image[:, 0].sum() == 0 and out.image[99].sum() == 0
    x0, z0 = out.origin_m
    assert x0 == pytest.approx(out.cloud[:, 0].min() - 0.01)
    assert z0 == pytest.approx(out.cloud[:, 2].min() - 0.01)


def test_rasterise_follows_the_authors_rule():
    # Mid-cell values: a value on a cell boundary may fall either side in float32.
    profile = np.array(
        [
            [0.50, -0.50],
            [0.605, -0.395],
            [0.555, -0.455],
            [1.485, -0.495],
            [1.495, -0.45],
            [0.70, 0.495],
        ],
        np.float32,
    )
    image, origin = rasterise(profile)
    assert origin == pytest.approx((0.49, -0.51))
    expected = np.zeros((100, 100), np.uint8)
    expected[98, 1] = 1  # the minimum lands in cell 1 (0.01 m)
    expected[88, 11] = 1  # 10.5 cm forward and up
    expected[94, 6] = 1
    expected[98, 99] = 1  # 98.5 cm forward: the last column
    # 99.5 cm beyond the minimum forward, or above it: dropped, as the authors drop
    # points beyond 0.99 m.
    np.testing.assert_array_equal(image, expected)


@pytest.mark.parametrize("beyond", [-0.6, -0.2, 0.4, None])
def test_a_level_line_sits_on_the_bottom_row_whatever_lies_beyond(beyond):
    # Level ground from 0.6 to 1.6 m ahead, then (beyond the image's 0.99 m) a descent, a
    # rise or nothing: the z shift takes the minimum of the points the x crop kept.
    x = np.arange(0.6, 1.58, 0.004)
    profile = [np.stack([x, np.zeros_like(x)], 1)]
    if beyond is not None:
        far = np.arange(1.65, 2.5, 0.004)
        profile.append(np.stack([far, np.full_like(far, beyond)], 1))
    image, (_, z0) = rasterise(np.concatenate(profile).astype(np.float32))
    rows, cols = np.nonzero(image)
    assert set(rows) == {98}  # the lowest row the one-cell shift allows (99 is the margin)
    assert cols.min() == 1 and cols.max() >= 97
    assert z0 == pytest.approx(-0.01)


def test_rasterise_shifts_z_by_the_points_the_x_crop_keeps():
    # A line descending 0.5 m over 2 m: the image holds its first 0.99 m, whose lowest
    # point (at 0.99 m) sits on the bottom row and whose highest point 25 cm above it.
    x = np.arange(0.0, 2.0, 0.002)
    image, _ = rasterise(np.stack([x, -0.25 * x], 1).astype(np.float32))
    rows, cols = np.nonzero(image)
    assert rows.max() == 98 and rows[cols == 1].min() == 98 - 24


def test_stairs_up_rise_in_the_image():
    q = tr.thigh_quaternion(-10, 0, 0)
    xyz, conf = tr.render(tr.stairs(0.15, 0.30), q, noise_m=0.005)
    out = preprocess(xyz, conf, q, PARAMS)
    image = out.image
    top = np.array([np.argmax(image[:, c]) if image[:, c].any() else -1 for c in range(100)])
    seen = top[top >= 0]
    # The highest occupied row never goes down (rows count downwards) by more than noise.
    assert np.all(np.diff(seen) <= 1)
    # The risers: columns with a vertical run of occupied cells about 15 cm high.
    runs = image.sum(axis=0)
    assert (runs >= 12).sum() >= 2


@pytest.mark.parametrize("terrain", [tr.level(), tr.stairs(0.17, 0.3), tr.ramp(-12)])
def test_heading_does_not_matter(terrain):
    images = []
    for yaw in (0, 100, -150):
        q = tr.thigh_quaternion(-8, 2, yaw)
        xyz, conf = tr.render(terrain, q)
        images.append(preprocess(xyz, conf, q, PARAMS).image)
    assert iou(images[0], images[1]) > 0.97 and iou(images[0], images[2]) > 0.97


@pytest.mark.parametrize(
    "terrain", [tr.stairs(0.15, 0.3), tr.stairs(0.15, 0.3, up=False), tr.ramp(15)]
)
def test_backends_agree(terrain):
    q = tr.thigh_quaternion(0, 2, 10)
    xyz, conf = tr.render(terrain, q, noise_m=0.005)
    a = preprocess(xyz, conf, q, PreprocessConfig(backend="numpy"))
    b = preprocess(xyz, conf, q, PreprocessConfig(backend="open3d"))
    assert a.ok and b.ok
    assert iou(a.image, b.image) > 0.85
    # compared in the image's 1 m: beyond it, at 2-2.5 m, points are sparse and the 3-D
    # radius filter drops more of them than the sagittal cell filter does
    na, nb = (int(np.sum(p.cloud[:, 0] < p.origin_m[0] + 1.0)) for p in (a, b))
    assert abs(na - nb) < 0.1 * na


def with_stray_points(xyz, conf, points_cam):
    xyz, conf = xyz.copy(), conf.copy()
    for k, p in enumerate(points_cam):
        xyz[0, k] = p
        conf[0, k] = 255
    return xyz, conf


@pytest.mark.parametrize("backend", BACKENDS)
def test_isolated_points_are_removed_before_the_shift(backend):
    q = tr.thigh_quaternion(0, 0, 0)
    xyz, conf = tr.render(tr.level(), q)
    # One flying pixel 30 cm under the floor, 0.8 m ahead in the corridor (camera frame:
    # the inverse of the leveling).
    stray = leveling_matrix(q).T @ np.array([0.8, 0.0, -0.85])
    xyz, conf = with_stray_points(xyz, conf, [stray])
    kept = preprocess(xyz, conf, q, PreprocessConfig(backend=backend))
    assert kept.cloud[:, 2].min() > -0.56
    assert set(np.nonzero(kept.image)[0]) == {98}
    raw = preprocess(xyz, conf, q, PreprocessConfig(backend=backend, outlier_min_points=0))
    assert raw.cloud[:, 2].min() < -0.84  # without removal it would shift the image
    rows = np.nonzero(raw.image)[0]
    assert (rows == 98).sum() == 1  # the ground is lifted, only the stray point is left


def test_low_confidence_pixels_are_ignored():
    q = tr.thigh_quaternion(-10, 0, 0)
    xyz, conf = tr.render(tr.level(), q)
    conf = conf.copy()
    conf[:, :] = 3
    conf[100:] = 200  # only the lower image rows are trusted
    near = preprocess(xyz, conf, q, PreprocessConfig(min_confidence=100))
    full = preprocess(xyz, conf, q, PARAMS)
    assert 0 < len(near.cloud) < len(full.cloud)
    assert near.cloud[:, 0].max() < full.cloud[:, 0].max() - 0.2  # lower rows = nearer


def assert_empty(out: Preprocessed, flag: str):
    assert not out.ok and out.flag == flag
    assert out.image.shape == (100, 100) and out.image.dtype == np.uint8
    assert out.image.sum() == 0
    assert out.cloud.shape == (0, 3) and out.profile.shape == (0, 2)


@pytest.mark.parametrize("backend", BACKENDS)
def test_degenerate_input_gives_an_empty_image_and_a_reason(backend):
    params = PreprocessConfig(backend=backend)
    q = tr.thigh_quaternion(-10, 0, 0)
    xyz, conf = tr.render(tr.level(), q)
    assert_empty(preprocess(xyz, np.zeros_like(conf), q, params), "no_valid_points")
    assert_empty(preprocess(np.full_like(xyz, np.nan), conf, q, params), "nan_input")
    assert_empty(preprocess(xyz, conf, np.full(4, np.nan), params), "bad_orientation")
    assert_empty(preprocess(xyz, conf, np.zeros(4), params), "bad_orientation")
    assert_empty(preprocess(xyz, conf, np.ones(3), params), "bad_orientation")
    assert_empty(preprocess(xyz[:, :, :2], conf, q, params), "bad_input")
    assert_empty(preprocess(xyz, conf[:10], q, params), "bad_input")
    # Thigh raised high: the camera looks 35 degrees above the horizon, at the sky.
    up = tr.thigh_quaternion(-70, 0, 0)
    sky_xyz, sky_conf = tr.render(tr.level(), up)
    assert_empty(preprocess(sky_xyz, sky_conf, up, params), "looking_up")
    # Points, but none in the corridor (all far to the side).
    side = np.zeros_like(xyz)
    side[..., 0] = 1.0
    side[..., 2] = 0.5
    assert_empty(preprocess(side, conf, q, params), "empty_corridor")


def test_some_nans_are_dropped_not_fatal():
    q = tr.thigh_quaternion(-10, 0, 0)
    xyz, conf = tr.render(tr.level(), q)
    xyz = xyz.copy()
    xyz[::2] = np.nan
    xyz[1::4, :, 1] = np.inf
    out = preprocess(xyz, conf, q, PARAMS)
    assert out.ok and np.all(np.isfinite(out.cloud))


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from([np.nan, np.inf, 0.0, 1e30]), st.floats(0, 1))
def test_never_raises(seed, special, fraction):
    rng = np.random.default_rng(seed)
    xyz = rng.normal(0, 2, (17, 23, 3)).astype(np.float32)
    xyz[rng.random((17, 23)) < fraction] = special
    conf = rng.integers(0, 3, (17, 23)).astype(np.uint8)
    q = rng.normal(size=4)
    for backend in BACKENDS:
        out = preprocess(xyz, conf, q, PreprocessConfig(backend=backend, min_points=1))
        assert out.image.shape == (100, 100) and out.image.dtype == np.uint8
        assert np.all(np.isfinite(out.cloud))
        assert out.ok == (out.image.sum() > 0)


def test_metadata_holds_every_parameter_and_the_mounting():
    params = PreprocessConfig(corridor_width_m=0.2, backend="open3d")
    data = metadata(params, MountingConfig(roll_deg=-2.0, pitch_deg=41.5))
    json.dumps(data)  # goes into recording and model metadata as is
    assert data["mounting_pitch_deg"] == 41.5 and data["mounting_roll_deg"] == -2.0
    assert data["mounting_yaw_deg"] == 0.0
    mounting = {"mounting_roll_deg", "mounting_pitch_deg", "mounting_yaw_deg"}
    assert PreprocessConfig(**{k: v for k, v in data.items() if k not in mounting}) == params


@pytest.mark.parametrize(
    "bad",
    [
        {"backend": "gpu"},
        {"cell_m": 0.0},
        {"grid_size": 0},
        {"corridor_width_m": -0.1},
        {"max_forward_m": -1.0},
    ],
)
def test_bad_params_are_named(bad):
    (key,) = bad
    assert key in [name for name, _ in PreprocessConfig(**bad).problems()]


def test_preprocess_frame_and_grid_size():
    q = tr.thigh_quaternion(-10, 0, 0)
    xyz, conf = tr.render(tr.stairs(0.15, 0.3), q)
    frame = DepthFrame(
        index=0,
        device_time_ns=0,
        host_time_ns=0,
        xyz=xyz,
        confidence=conf,
        gray=np.zeros(conf.shape, np.uint16),
    )
    out = preprocess_frame(frame, q, PreprocessConfig(grid_size=64, cell_m=0.02))
    assert out.ok and out.image.shape == (64, 64)


def test_bench_reports_both_backends():
    from capture.bench.components import bench_preprocess

    result = bench_preprocess(frames=4)
    assert result["numpy_median_ms"] > 0 and result["open3d_median_ms"] > 0
    assert result["numpy_corridor_points"] > 100


def test_the_levelings_rotation_is_quat_to_matrix_bit_for_bit():
    from devices.rotations import quat_to_matrix
    from inference.preprocess import _rotation

    rng = np.random.default_rng(11)
    for _ in range(2000):
        q = rng.standard_normal(4)
        q /= np.linalg.norm(q) * rng.uniform(0.9, 1.1)
        assert np.array_equal(_rotation(q), quat_to_matrix(q))
