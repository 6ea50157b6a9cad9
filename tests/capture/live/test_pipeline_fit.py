"""A profile fitted elsewhere (replay's reader process) gives the pipeline the same features
and, through the geometry cue, the same fused decisions as the pipeline fitting it itself."""

import pickle

import numpy as np

from capture.config import Config
from capture.live.pipeline import Pipeline
from devices.frames import DepthFrame
from inference.config import PreprocessConfig
from inference.features import fit_profile
from tests import terrain_raycast as tr
from tests.capture.live.sessions import StandInClassifier


def _frames():
    """A walk over level ground, stairs up and down and a ramp, frame by frame."""
    rng = np.random.default_rng(5)
    course = [tr.level()] * 3 + [tr.stairs(0.17, 0.3)] * 4
    course += [tr.stairs(0.17, 0.3, up=False)] * 4 + [tr.ramp(10.0)] * 4
    for k, terrain in enumerate(course):
        q = tr.thigh_quaternion(rng.uniform(-20, 10), rng.uniform(-3, 3), 0.0)
        xyz, conf = tr.render(terrain, q, height_m=0.55, noise_m=0.01, seed=k)
        t = 1_000_000_000 + k * 22_222_222
        yield DepthFrame(k, t, t + 3_000_000, xyz, conf, np.zeros(conf.shape, np.uint16)), q


def test_a_fit_made_elsewhere_changes_no_feature_and_no_decision():
    config = Config()
    config.fusion.method = "steady+geometry"  # the features feed the fusion back

    def pipeline():
        return Pipeline(PreprocessConfig(), StandInClassifier(), config.fusion.make())

    here, elsewhere = pipeline(), pipeline()
    kinds = set()
    for frame, q in _frames():
        a = here.process(frame, q)
        pre = elsewhere.prepare(frame, q)
        fit = pickle.loads(pickle.dumps(fit_profile(pre.profile).slim())) if pre.ok else None
        pre.profile = np.zeros((0, 2), np.float32)  # as the reader process sends it
        b = elsewhere.process(frame, q, prepared=pre, profile_fit=fit)
        assert a.features == b.features
        assert a.fused_dict() == b.fused_dict()
        kinds.add(a.features.get("kind"))
    assert {"stairs", "ramp", "level"} <= kinds
