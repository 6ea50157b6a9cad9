import threading

import numpy as np

from capture.live.pipeline import OrientationTrack
from devices.rotations import quat_from_euler, quat_to_euler


def test_interpolates_between_samples():
    track = OrientationTrack()
    track.add(1_000_000_000, quat_from_euler(0, 0.0, 0))
    track.add(1_010_000_000, quat_from_euler(0, 0.2, 0))
    q, dist = track.at(1_002_500_000)
    np.testing.assert_allclose(quat_to_euler(q), [0, 0.05, 0], atol=1e-9)
    assert dist == 2_500_000


def test_holds_the_nearest_outside_and_ignores_out_of_order():
    track = OrientationTrack()
    assert track.at(5)[0] is None
    track.add(100, quat_from_euler(0, 0.1, 0))
    track.add(50, quat_from_euler(0, 0.9, 0))  # older than the last: ignored
    q, dist = track.at(400)
    np.testing.assert_allclose(quat_to_euler(q)[1], 0.1)
    assert dist == 300


def test_forgets_beyond_its_span():
    track = OrientationTrack(span_s=1.0)
    for i in range(300):
        track.add(i * 10_000_000, quat_from_euler(0, 0, 0))
    assert len(track._times) <= 101


def test_wait_until_returns_when_a_later_sample_arrives():
    track = OrientationTrack()
    track.add(0, quat_from_euler(0, 0, 0))
    threading.Timer(0.05, lambda: track.add(2000, quat_from_euler(0, 0, 0))).start()
    assert track.wait_until(1000, 60.0)  # returns once the sample came (a bound only)
    assert not track.wait_until(5000, 0.01)


def test_past_the_newest_sample_the_rate_of_turn_carries_the_orientation_on():
    track = OrientationTrack()
    rate = np.array([0.0, 2.0, 0.0])  # 2 rad/s about the body's y axis (a thigh swing)
    track.add(0, quat_from_euler(0, 0.1, 0), rate)
    q, ahead = track.at(10_000_000)  # 10 ms later: 0.02 rad further
    np.testing.assert_allclose(quat_to_euler(q), [0, 0.12, 0], atol=1e-9)
    assert ahead == 10_000_000
    q, _ = track.at(1_000_000_000)  # far beyond: held, not flung on
    np.testing.assert_allclose(quat_to_euler(q), [0, 0.1, 0], atol=1e-9)


def test_the_configured_pipeline_and_its_software_record():
    from capture import __version__
    from capture.config import Config
    from capture.live.pipeline import build_pipeline, software_metadata
    from inference.fusion import ForwardFilter

    config = Config()
    config.fusion.method = "forward"
    config.preprocess.max_forward_m = 2.0

    class Classifier:
        metadata = {"weights_sha256": "cafe"}

    pipeline = build_pipeline(config, Classifier())
    assert isinstance(pipeline.fusion, ForwardFilter)
    assert pipeline.params.max_forward_m == 2.0
    software = software_metadata(config, pipeline, replay_of="a.mcap")
    assert software["walkcap_version"] == __version__
    assert software["model_hash"] == "cafe" and software["model_path"] == "bundled"
    assert software["fusion_method"] == "forward" and software["replay_of"] == "a.mcap"
    assert software["preprocess"]["max_forward_m"] == 2.0
