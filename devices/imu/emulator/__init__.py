"""An Xsens-style IMU on a pseudo-terminal: the mock backend is the real driver against this.

The emulator is the device side of a serial line. It answers what a device of its family
answers on open and configuration, so that Xsens' own host library (xspublic) opens it,
streams MTData2 at the configured rate from its own drifting clock, paces each message by
its wire time, and injects faults on command. Runs in a daemon thread of the calling
process (tests, the mock backend) or standalone (`walkcap imu emulate`).

    device.py     ImuEmulator: life cycle, configuration and measurement, faults
    line.py       PtyLine: the pty with a stable path, UART pacing, the output buffer
    settings.py   DeviceSettings: identity, stored settings, outputs, and their answers
    samples.py    EmulatorClock, Motion (each sample's values), gait_orientation
"""

from devices.imu.emulator.device import FAULTS, ImuEmulator
from devices.imu.emulator.line import PORT_NAME_MAX
from devices.imu.emulator.samples import EmulatorClock, gait_orientation

__all__ = ["FAULTS", "PORT_NAME_MAX", "EmulatorClock", "ImuEmulator", "gait_orientation"]
