"""The pipeline's frame: what the fusion is shown besides the CNN's output."""

import numpy as np

from capture.live.pipeline import Pipeline
from devices.rotations import quat_from_euler
from devices.simulator.synthetic import synthetic_frame
from inference.config import PreprocessConfig
from inference.features import ground_ahead, shown_mode
from inference.fusion import GeometryFusion


def test_the_pipeline_shows_a_geometry_fusion_each_frames_features():

    class Spy(GeometryFusion):
        def see_geometry(self, mode, ahead=-1):
            seen.append(mode)
            ahead_seen.append(ahead)
            super().see_geometry(mode, ahead)

    class Classifier:
        def predict(self, image):
            return np.array([0.6, 0.1, 0.1, 0.1, 0.1])

    seen: list = []
    ahead_seen: list = []
    pipeline = Pipeline(PreprocessConfig(), Classifier(), Spy())
    results = []
    for k in (0, 11, 22):  # a thigh swinging (synthetic_frame's)
        q = quat_from_euler(0.0, np.radians(20.0) * np.sin(2 * np.pi * k / 45.0), 0.0)
        results.append(pipeline.process(synthetic_frame(k, 1_000_000 * k), q))
    shown = [shown_mode(r.features.get("kind"), r.features.get("direction")) for r in results]
    assert seen == shown and -1 not in seen  # each frame's features, after its push
    ahead = [ground_ahead(r.features.get("ahead_slope_deg")) for r in results]
    assert ahead_seen == ahead and set(ahead) != {-1}  # and the ground ahead, seen or not


def test_the_pipeline_hands_a_step_fusion_the_gait_events_up_to_each_frame():
    from devices.frames import GaitEvent
    from inference.fusion import StepFusion

    class Spy(StepFusion):
        def see_gait(self, event):
            seen.append((self._frame, event))
            super().see_gait(event)

        def push(self, probabilities, elevation_deg=None):
            elevations.append(elevation_deg)
            return super().push(probabilities, elevation_deg)

    class Classifier:
        def predict(self, image):
            return np.array([0.6, 0.1, 0.1, 0.1, 0.1])

    seen: list = []
    elevations: list = []
    pipeline = Pipeline(PreprocessConfig(), Classifier(), Spy())
    frames = [synthetic_frame(k, 100_000_000 * k) for k in range(3)]  # 0, 0.1, 0.2 s
    # from the IMU's thread, ahead of the frames: each waits for the first frame at or
    # after its time
    pipeline.see_gait(GaitEvent(50_000_000, "heel_contact", "imu"))
    pipeline.see_gait(GaitEvent(100_000_000, "toe_off", "imu"))
    # known only at 0.15 s (the IMU sample that revealed it): after frame 1
    pipeline.see_gait(GaitEvent(110_000_000, "heel_contact", "imu"), 150_000_000)
    pipeline.see_gait(GaitEvent(250_000_000, "heel_contact", "imu"))
    q = quat_from_euler(0.0, 0.0, 0.0)
    for f in frames:
        pipeline.process(f, q)
    # two before frame 1's push (the fusion had taken frame 0), one before frame 2's; the
    # last waits for a frame at 0.25 s
    assert seen == [(1, "heel_contact"), (1, "toe_off"), (2, "heel_contact")]
    # each frame's camera elevation goes with its push: the steps' timing uses it
    assert len(elevations) == 3 and all(np.isfinite(e) and -90 < e < 0 for e in elevations)
    # a fusion that does not act at steps is never handed any
    plain = Pipeline(PreprocessConfig(), Classifier(), GeometryFusion())
    plain.see_gait(GaitEvent(0, "heel_contact", "imu"))
    assert not plain._gait


def _tilted_walk(pipeline, frames: int, tilt_deg: float):
    """Frames of synthetic_frame's level walk through an IMU whose pitch is off by tilt_deg."""
    from devices.rotations import quat_multiply

    error = quat_from_euler(0.0, np.radians(tilt_deg), 0.0)
    out = []
    for k in range(frames):
        swing = quat_from_euler(0.0, np.radians(20.0) * np.sin(2 * np.pi * k / 45.0), 0.0)
        out.append(
            pipeline.process(synthetic_frame(k, 66_666_667 * k), quat_multiply(error, swing))
        )
    return out


def test_the_pipeline_takes_the_imus_tilt_learned_on_level_ground_off_the_slope():
    class Level:
        def predict(self, image):
            return np.array([0.9, 0.025, 0.025, 0.025, 0.025])

    results = _tilted_walk(Pipeline(PreprocessConfig(), Level(), GeometryFusion()), 60, 2.0)
    late = [r.features for r in results[30:] if r.features.get("kind") == "level"]
    assert len(late) >= 15
    raw = np.median([f["slope_deg"] + f["tilt_offset_deg"] for f in late])
    assert abs(raw + 2.0) < 0.5  # the tilted IMU tilts the leveled ground by 2 deg
    assert abs(np.median([f["slope_deg"] for f in late])) < 0.3  # reported net of it
    assert abs(results[-1].features["tilt_offset_deg"] - raw) < 0.3


def test_the_pipeline_learns_no_tilt_while_the_decision_is_not_level_ground():
    class Ramp:
        def predict(self, image):
            return np.array([0.025, 0.025, 0.025, 0.9, 0.025])

    results = _tilted_walk(Pipeline(PreprocessConfig(), Ramp(), GeometryFusion()), 30, 2.0)
    assert all(r.features.get("tilt_offset_deg", 0.0) == 0.0 for r in results)
