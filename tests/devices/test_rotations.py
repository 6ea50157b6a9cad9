import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from devices import rotations as r

angles = st.floats(-3.0, 3.0)


@given(angles, st.floats(-1.5, 1.5), angles)
def test_euler_round_trip(roll, pitch, yaw):
    q = r.quat_from_euler(roll, pitch, yaw)
    np.testing.assert_allclose(r.quat_to_euler(q), [roll, pitch, yaw], atol=1e-6)


@given(angles, st.floats(-1.5, 1.5), angles)
def test_matrix_round_trip(roll, pitch, yaw):
    q = r.quat_from_euler(roll, pitch, yaw)
    q = q if q[0] >= 0 else -q
    np.testing.assert_allclose(r.matrix_to_quat(r.quat_to_matrix(q)), q, atol=1e-9)


def test_product_composes_matrices():
    a = r.quat_from_euler(0.1, 0.2, 0.3)
    b = r.quat_from_euler(-0.4, 0.5, 0.6)
    np.testing.assert_allclose(
        r.quat_to_matrix(r.quat_multiply(a, b)),
        r.quat_to_matrix(a) @ r.quat_to_matrix(b),
        atol=1e-12,
    )


def test_positive_pitch_points_the_camera_down():
    forward_cam = np.array([0.0, 0.0, 1.0])
    v = r.mounting_matrix(0, 30) @ forward_cam
    assert v[2] < 0 and v[0] > 0
    np.testing.assert_allclose(np.degrees(np.arcsin(-v[2])), 30, atol=1e-9)


def test_slerp_halfway():
    a = r.quat_from_euler(0, 0, 0)
    b = r.quat_from_euler(0, 0, 1.0)
    np.testing.assert_allclose(r.quat_to_euler(r.quat_slerp(a, b, 0.5)), [0, 0, 0.5], atol=1e-9)
