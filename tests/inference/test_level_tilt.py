"""The IMU's tilt error learned on level ground: taken off level and ramp slopes alike,
frozen off level ground, bounded."""

import numpy as np

from inference import level_tilt as lt

FRAME_NS = round(1e9 / 15)


def run(frames, state=None):
    """frames: (decision, kind, slope) per frame at 15 fps; the corrected slopes and the
    final estimate (each frame corrected by what the earlier ones taught)."""
    state = state or lt.TiltEstimate()
    out = []
    for k, (decision, kind, slope) in enumerate(frames):
        out.append(lt.correct(state, slope))
        state = lt.update(state, decision, kind, slope, k * FRAME_NS)
    return np.array(out, dtype=float), state


def test_a_constant_tilt_on_level_ground_is_learned_and_taken_off_a_ramp_after_it():
    rng = np.random.default_rng(1)
    level = [("LG", "level", 2.2 + 0.8 * rng.standard_normal()) for _ in range(150)]
    ramp = [("RA", "ramp", 6.0 + 2.2) for _ in range(60)]  # a 6 deg ramp, tilted alike
    slopes, state = run(level + ramp)
    assert abs(state.offset_deg - 2.2) < 0.3
    assert abs(np.median(slopes[60:150])) < 0.3  # level ground reads level
    assert np.allclose(slopes[150:], 6.0, atol=0.3)  # the ramp keeps its own slope


def test_frozen_off_level_ground_so_a_ramp_is_not_learned_away():
    level = [("LG", "level", 0.0)] * 60
    # up a ramp: whether the decision, the features or both say so, nothing is learned
    ramp = [("RA", "ramp", 5.0)] * 100 + [("RA", "level", 5.0)] * 50 + [("LG", "ramp", 5.0)] * 50
    slopes, state = run(level + ramp)
    assert state.offset_deg == 0.0 and state.frames == 60
    assert np.all(slopes[60:] == 5.0)


def test_a_missed_ramp_decided_level_is_gated_out_and_the_estimate_is_bounded():
    # level ground decided level at 0 deg, then a 1:12 ramp (4.8 deg) the fusion still calls level
    slopes, state = run([("LG", "level", 0.0)] * 60 + [("LG", "level", 4.8)] * 100)
    assert state.offset_deg == 0.0 and np.all(slopes[60:] == 4.8)
    # a tilt past the bound is never taken off in full
    _, state = run([("LG", "level", 3.9)] * 300)
    assert state.offset_deg == lt.MAX_DEG


def test_nothing_to_correct_and_no_slope_teach_nothing():
    state = lt.TiltEstimate(1.0, 40, 0)
    assert lt.correct(state, None) is None
    assert lt.update(state, "LG", "level", None, FRAME_NS) == state
    assert lt.update(state, "LG", "level", float("nan"), FRAME_NS) == state
    assert lt.update(state, None, "level", 1.0, FRAME_NS) == state
