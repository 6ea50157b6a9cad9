"""Fixtures of the device tests."""

import pytest

from devices.imu import EmulatedImu


@pytest.fixture
def mock_imu():
    """make(**kw): an EmulatedImu (the emulator on a pty), closed after the test."""
    imus = []

    def make(**kw):
        imu = EmulatedImu(**kw)
        imus.append(imu)
        return imu

    yield make
    for imu in imus:
        imu.close()
