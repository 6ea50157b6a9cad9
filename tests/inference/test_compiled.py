"""The compiled steps (inference.corridor, inference.profile_fit) against the
straightforward numpy functions they stand in for, on the frames of simulated walks: the
preprocessing bit for bit; the terrain features the same, their floats to the last bits
(numba sums in loop order where numpy sums pairwise and its BLAS as it does)."""

import dataclasses
import math
import pickle

import numpy as np
import pytest

from capture.recording import topics as T
from devices.frames import MODES
from devices.simulator import Simulator, make_course
from inference.config import PreprocessConfig
from inference.features import classify, fit_profile
from inference.preprocess import preprocess, preprocess_ranges

PARAMS = PreprocessConfig()
# numba's float sums against numpy's: over 1,600 profiles of the two walks (800 frames of
# each) the largest differences are 3e-12 m and 1.2e-9 degrees (a short segment's angle:
# 2.5 cm long)
METRES, DEGREES = 1e-9, 1e-6
HINTS = (None, *MODES)


def walk_frames(preset: str, seed: int, count: int):
    """`count` frames spread over a simulated walk of the course, each with the thigh's
    orientation at its time."""
    sim = Simulator(make_course(preset, seed), seed=seed, cast_threads=1)
    for k, t in enumerate(np.linspace(0.0, sim.duration_s, count, endpoint=False)):
        yield sim.render(float(t), index=k), sim.thigh_quaternion(float(t))


def frames_of(count: int) -> list:
    return [*walk_frames("indoor", 5, count), *walk_frames("outdoor", 6, count)]


@pytest.fixture(scope="module")
def frames():
    return frames_of(60)


def profiles_of(frames) -> list[np.ndarray]:
    out = []
    for frame, q in frames:
        pre = preprocess(frame.xyz, frame.confidence, q, PARAMS)
        if pre.ok:
            out.append(pre.profile)
    return out


def assert_same_preprocessing(a, b) -> None:
    for name in ("image", "cloud", "profile"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), name
    assert (a.flag, a.details, a.origin_m) == (b.flag, b.details, b.origin_m)
    assert a.elevation_deg == b.elevation_deg or (
        math.isnan(a.elevation_deg) and math.isnan(b.elevation_deg)
    )


def test_the_compiled_preprocessing_is_numpys_bit_for_bit(frames):
    seen = 0
    for frame, q in frames:
        reference = preprocess(frame.xyz, frame.confidence, q, PARAMS, compiled=False)
        assert_same_preprocessing(preprocess(frame.xyz, frame.confidence, q, PARAMS), reference)
        seen += reference.ok
    assert seen >= 0.8 * len(frames)  # images, not only flags


def test_a_recordings_ranges_preprocess_as_its_points_do(frames):
    """replay's reader preprocesses a frame from its recorded ranges and the rays, without
    its points: the same as the points rebuilt from them (capture.recording.topics)."""
    rays = frames[0][0].geometry.rays().astype(np.float32)
    for frame, q in frames[::4]:
        mm = T.range_mm(frame.xyz, frame.confidence)
        xyz = T.xyz_from_range(mm, rays)
        assert_same_preprocessing(
            preprocess_ranges(mm, rays, frame.confidence, q, PARAMS),
            preprocess(xyz, frame.confidence, q, PARAMS, compiled=False),
        )


def test_degenerate_frames_give_the_same_flags():
    rng = np.random.default_rng(3)
    xyz = rng.uniform(-1, 1, (171, 224, 3)).astype(np.float32)
    confidence = np.zeros((171, 224), np.uint8)
    level = np.array([1.0, 0.0, 0.0, 0.0])
    for conf, points in (
        (confidence, xyz),  # nothing valid
        (confidence + 255, np.full_like(xyz, np.nan)),  # nothing finite
        (confidence + 255, xyz * 0.01),  # nothing in the corridor's box
    ):
        assert_same_preprocessing(
            preprocess(points, conf, level, PARAMS),
            preprocess(points, conf, level, PARAMS, compiled=False),
        )


def assert_same_features(a, b) -> None:
    for field in dataclasses.fields(a):
        x, y = getattr(a, field.name), getattr(b, field.name)
        if field.name == "segments":
            assert len(x) == len(y)
            for p, q in zip(x, y):  # x0, z0, x1, z1, angle
                assert np.allclose(p[:4], q[:4], rtol=0, atol=METRES), (p, q)
                assert abs(p[4] - q[4]) <= DEGREES, (p, q)
        elif isinstance(x, float) and isinstance(y, float):
            tolerance = DEGREES if field.name.endswith("_deg") else METRES
            assert abs(x - y) <= tolerance, (field.name, x, y)
        else:
            assert x == y, (field.name, x, y)


def assert_compiled_features_are_numpys(profiles) -> None:
    for profile in profiles:
        reference = fit_profile(profile, PARAMS.max_forward_m, compiled=False)
        fit = fit_profile(profile, PARAMS.max_forward_m)
        # the same segments: the same slices of the profile, the same points their own
        assert [(s.first, s.stop, s.count) for s in fit.segments] == [
            (s.first, s.stop, s.count) for s in reference.segments
        ]
        for s, r in zip(fit.segments, reference.segments):
            assert np.array_equal(np.sort(s.points, axis=0), np.sort(r.points, axis=0))
            for name in ("level", "x_p2", "x_median", "x_p98"):  # numpy's order statistics
                assert getattr(s, name) == getattr(r, name), name
        for hint in HINTS:
            assert_same_features(classify(fit, hint), classify(reference, hint))


def test_the_compiled_features_are_numpys(frames):
    profiles = profiles_of(frames)
    assert len(profiles) >= 0.8 * len(frames)
    assert_compiled_features_are_numpys(profiles)


@pytest.mark.slow
def test_the_compiled_features_are_numpys_over_whole_walks():
    assert_compiled_features_are_numpys(profiles_of(frames_of(400)))


def test_a_fit_without_its_points_classifies_the_same(frames):
    """replay sends the fit to the process that classifies without the points."""
    for profile in profiles_of(frames[::3]):
        fit = fit_profile(profile, PARAMS.max_forward_m)
        slim = pickle.loads(pickle.dumps(fit_profile(profile, PARAMS.max_forward_m).drop_points()))
        assert all(s.index is None and s.profile is None for s in slim.segments)
        for hint in HINTS:
            assert classify(slim, hint) == classify(fit, hint)


def test_the_clouds_thinning_keeps_the_first_point_of_each_voxel_as_np_unique_does(frames):
    """capture.recording.encode.thin_cloud's kernel against numpy's unique voxel keys."""
    from inference.corridor import first_in_voxel

    voxel = 0.02
    for frame, q in frames[::6]:
        cloud = preprocess(frame.xyz, frame.confidence, q, PARAMS).cloud
        cloud = np.concatenate([cloud, -cloud[::7]])  # both signs, repeated voxels
        cells = np.floor(cloud / voxel).astype(np.int64) + (1 << 20)
        key = (cells[:, 0] << 42) | (cells[:, 1] << 21) | cells[:, 2]
        _, first = np.unique(key, return_index=True)
        kept = first_in_voxel(cloud, np.float32(voxel))
        assert np.array_equal(kept, np.sort(first)) and 0 < len(kept) < len(cloud)


def test_the_recorded_clouds_rounding_is_numpys_bit_for_bit(frames):
    """capture.recording.topics.cloud_message's kernel: finite points, sorted by x
    (stable: equal x keep their order), rounded to the quantum."""
    from inference.corridor import quantized_cloud

    quantum = T.CLOUD_QUANTUM_M
    for frame, q in frames[::6]:
        cloud = preprocess(frame.xyz, frame.confidence, q, PARAMS).cloud.copy()
        cloud[1::9, 0] = cloud[::9, 0][: len(cloud[1::9])]  # equal x
        cloud[::31, 1] = np.nan
        points = cloud.astype(np.float64)
        points = points[np.all(np.isfinite(points), axis=1)]
        points = points[np.argsort(points[:, 0], kind="stable")]
        reference = (np.rint(points / quantum) * quantum).astype("<f4")
        assert quantized_cloud(cloud, quantum).tobytes() == reference.tobytes()
        assert 0 < len(reference) < len(cloud)
