"""The one synthetic IMU orientation error: a session bias and per-sample noise."""

import numpy as np

from devices.orientation_error import OrientationError, OrientationErrorModel
from devices.rotations import quat_conjugate, quat_from_euler, quat_multiply, quat_to_euler


def _error_deg(measured, true):
    return np.degrees(quat_to_euler(quat_multiply(measured, quat_conjugate(true))))


def test_bias_holds_over_a_session_and_noise_has_its_size():
    rng = np.random.default_rng(3)
    error = OrientationError(OrientationErrorModel(noise_deg=0.7, bias_deg=2.0), rng)
    true = quat_from_euler(0.1, -0.4, 1.0)
    errors = np.array([_error_deg(error.apply(true), true) for _ in range(4000)])
    bias = np.degrees(quat_to_euler(error.bias))
    assert np.allclose(errors[:, :2].mean(axis=0), bias[:2], atol=0.05)
    assert abs(bias[2]) < 1e-9  # roll and pitch only: gravity bounds those
    assert np.allclose(errors.std(axis=0), 0.7, rtol=0.1)


def test_no_error_returns_the_truth_and_draws_nothing():
    rng = np.random.default_rng(0)
    error = OrientationError(OrientationErrorModel(noise_deg=0.0, bias_deg=0.0), rng)
    q = quat_from_euler(0.2, 0.3, 0.4)
    assert np.array_equal(error.apply(q), q)
    assert rng.normal() == np.random.default_rng(0).normal()


def test_the_same_seed_gives_the_same_error():
    model = OrientationErrorModel()
    q = quat_from_euler(0.0, -0.5, 0.0)
    a = OrientationError(model, np.random.default_rng(9))
    b = OrientationError(model, np.random.default_rng(9))
    assert all(np.array_equal(a.apply(q), b.apply(q)) for _ in range(10))
