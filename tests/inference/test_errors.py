"""The shape of a classifier's errors on hand-built sequences with known answers."""

import numpy as np
import pytest

from inference.evaluation import errors as er

LG, US, DR = 0, 1, 4


def _probs(decisions, sure):
    """Probabilities whose argmax is `decisions`, the chosen mode at `sure`."""
    p = np.full((len(decisions), 5), 0.0)
    for k, (d, s) in enumerate(zip(decisions, sure)):
        p[k] = (1 - s) / 4
        p[k, d] = s
    return p


def test_runs_confidence_and_changes():
    t = np.arange(40) / 10.0  # 10 fps
    ref = np.full(40, LG)
    ref[30:] = US  # a change at 3.0 s
    dec = ref.copy()
    dec[5] = DR  # a lone error
    dec[10:14] = US  # a run of 4
    dec[29] = US  # one frame early, 0.1 s before the change
    sure = np.full(40, 0.97)
    sure[5], sure[10:14] = 0.5, [0.95, 0.92, 0.6, 0.55]
    shape = er.error_shape(dec, ref, _probs(dec, sure), t, 4 / 6)
    assert (shape.frames, shape.errors) == (40, 6)
    assert shape.runs == 3 and shape.run_lengths[[1, 4]].tolist() == [2, 1]
    assert shape.in_runs == pytest.approx(4 / 6)
    assert shape.run_histogram() == [2, 0, 1, 0, 0]
    assert shape.confident_wrong == pytest.approx(3 / 6)  # 0.95, 0.92 and the early 0.97
    assert shape.near_change_share == pytest.approx(1 / 6)
    assert shape.confusions == {(LG, DR): 1, (LG, US): 5}
    assert shape.runs_per_min == pytest.approx(3 / (4 / 6))


def test_unscored_frames_split_runs_and_gait_phases():
    t = np.arange(20) / 10.0
    ref = np.full(20, LG)
    ref[8] = -1  # no reference here: neither right nor wrong
    dec = np.full(20, LG)
    dec[6:12] = US  # wrong around the unscored frame: two runs
    shape = er.error_shape(dec, ref, _probs(dec, np.full(20, 0.9)), t, 2 / 6, [0.0, 1.0], [0.6])
    assert shape.frames == 19 and shape.errors == 5
    assert shape.runs == 2 and shape.run_lengths[[2, 3]].tolist() == [1, 1]
    # stance 0.0-0.6 s (frames 0-5), swing 0.6-1.0 s (frames 6-9 but the unscored 8); after
    # the last event: neither
    assert shape.stance == (6, 0) and shape.swing == (3, 3)
    assert shape.swing_error_rate == 1.0 and shape.stance_error_rate == 0.0


def test_pooled_and_summary():
    t = np.arange(10) / 10.0
    a = er.error_shape(np.ones(10, int), np.zeros(10, int), _probs([1] * 10, [0.99] * 10), t, 1.0)
    b = er.error_shape(np.zeros(10, int), np.zeros(10, int), _probs([0] * 10, [0.8] * 10), t, 1.0)
    p = er.pooled([a, b])
    assert (p.frames, p.errors, p.runs, p.minutes) == (20, 10, 1, 2.0)
    assert p.run_lengths[er.RUN_CAP] == 1  # a run of 10: counted with the longest
    s = er.summary(p)
    assert s["error_rate"] == pytest.approx(0.5) and s["run_lengths"]["9+"] == 1
    assert s["confidence_wrong_median"] == pytest.approx(0.99, abs=1e-3)  # binned by 0.001
    assert s["confidence_right_median"] == pytest.approx(0.8, abs=1e-3)
    assert s["error_rate_swing"] is None  # no gait events
