"""The IMU: one small interface, a registry of backends, the Xbus driver and its emulator.

    imu = open_imu(config.imu)          # the configured backend, not yet opened
    with imu:                           # opened, configured, streaming; closed on the way out
        sample = imu.recv(timeout=0.5)  # ImuSample or None
        imu.status(); imu.poll_events()

    base.py       Imu (the surface every backend shares), BACKENDS, open_imu(), register_backend()
    link.py       XbusLink: Xbus frames over a serial port, a request and its reply
    outputs.py    the output configuration fitted and checked; MTData2 values -> ImuSample
    driver.py     XbusImu: the device's state machine (configuration, measurement, reconnect)
    emulated.py   EmulatedImu: the mock backend, the driver against the emulator
    clock.py      DeviceClock: SampleTimeFine onto the session clock
    family.py     the MTi families: outputs, rates, settings-write times
    emulator/     ImuEmulator: an Xsens-style MTi on a pseudo-terminal

There is one real driver, `XbusImu` (Xsens MTi over pyserial); the mock backend,
`EmulatedImu`, is that same driver talking to an `ImuEmulator` on a pseudo-terminal.
"""

import importlib

from devices.imu.base import BACKENDS, Imu, open_imu, register_backend

# The driver and the emulator load on first use: the registry and open_imu() alone are
# what the CLI's parser needs, and --help stays fast.
_LAZY = {
    "XbusImu": "devices.imu.driver",
    "device_id_text": "devices.imu.driver",
    "EmulatedImu": "devices.imu.emulated",
}

__all__ = [
    "BACKENDS",
    "EmulatedImu",
    "Imu",
    "XbusImu",
    "device_id_text",
    "open_imu",
    "register_backend",
]


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(_LAZY[name]), name)
    globals()[name] = value
    return value
