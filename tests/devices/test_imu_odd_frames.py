"""A checksum-valid frame the decoder cannot take as it is never drops the IMU."""

from __future__ import annotations

import pytest

from devices import xbus
from tests.devices.imu_streams import collect, kinds

pytestmark = pytest.mark.realtime


def test_a_checksum_valid_frame_with_a_repeated_output_never_drops_the_imu(mock_imu):
    """Two quaternions in 16.32 fixed point, then temperature in 16.32 and in float32: the
    payload is decoded once per output, the stream goes on and the IMU is never lost."""
    quaternion = xbus.encode_packet("quaternion", (1.0, 0.0, 0.0, 0.0), xbus.FP1632)
    temperature = xbus.encode_packet("temperature", 20.0, xbus.FP1632) + xbus.encode_packet(
        "temperature", 21.0, xbus.FLOAT32
    )
    odd = xbus.build(xbus.MID.MTDATA2, quaternion + quaternion) + xbus.build(
        xbus.MID.MTDATA2, temperature
    )
    imu = mock_imu(rate_hz=100)
    imu.start()
    collect(imu, 0.3)
    imu.emulator.inject("corrupt", count=0, garbage=odd * 3)
    after = collect(imu, 0.8)
    assert len(after) > 60  # 100 Hz all along: no gap
    assert "lost" not in kinds(imu.poll_events())
    assert imu.status().state != "lost"
