"""The one synthetic IMU orientation error: the MTi 1-series' accuracy, drifting slowly."""

import math

import numpy as np
import pytest

from devices.orientation_error import NO_ERROR, OrientationError, OrientationErrorModel
from devices.rotations import quat_conjugate, quat_from_euler, quat_multiply, quat_to_euler


def _error_deg(measured, true):
    return np.degrees(quat_to_euler(quat_multiply(measured, quat_conjugate(true))))


def test_roll_and_pitch_error_has_the_datasheet_rms_and_drifts_slowly():
    model = OrientationErrorModel()  # 1.0 deg RMS roll/pitch, tau 120 s
    true = quat_from_euler(0.1, -0.4, 1.0)
    first, later, next_frame = [], [], []
    for seed in range(1500):  # sessions
        error = OrientationError(model, np.random.default_rng(seed))
        first.append(_error_deg(error.apply(true, 0.0), true))
        next_frame.append(_error_deg(error.apply(true, 1 / 15), true))
        later.append(_error_deg(error.apply(true, 60.0), true))
    first, later, next_frame = map(np.array, (first, later, next_frame))
    rms = np.sqrt(np.mean(first**2, axis=0))
    assert rms[:2] == pytest.approx(model.rms_deg[:2], rel=0.06)  # the datasheet's 1.0 deg
    assert rms[2] == pytest.approx(2.0, rel=0.06)
    # Not independent per frame: one frame later the error has hardly moved (white part
    # and drift: ~0.08 deg), a minute later it is correlated by exp(-60 / 120).
    step = next_frame - first
    assert np.sqrt(np.mean(step[:, :2] ** 2)) < 0.12
    corr = np.corrcoef(first[:, 1], later[:, 1])[0, 1]
    assert corr == pytest.approx(math.exp(-0.5), abs=0.06)


def test_no_error_returns_the_truth():
    error = OrientationError(NO_ERROR, np.random.default_rng(0))
    q = quat_from_euler(0.2, 0.3, 0.4)
    assert np.array_equal(error.apply(q, 0.0), q)
    assert np.array_equal(error.apply(q, 5.0), q)


def test_the_same_seed_gives_the_same_error_and_time_never_runs_back():
    model = OrientationErrorModel()
    q = quat_from_euler(0.0, -0.5, 0.0)
    a = OrientationError(model, np.random.default_rng(9))
    b = OrientationError(model, np.random.default_rng(9))
    assert all(np.array_equal(a.apply(q, k / 15), b.apply(q, k / 15)) for k in range(10))
    state = a.error_at(1.0).copy()
    np.testing.assert_array_equal(a.error_at(0.5), state)  # an older time: the state holds


def test_a_negative_size_is_refused():
    with pytest.raises(ValueError):
        OrientationErrorModel(roll_pitch_deg=-1.0)
