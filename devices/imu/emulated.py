"""The mock IMU backend: the real Xbus driver against an `ImuEmulator` on a pty it owns.

The mock exercises the same driver, pyserial and termios as a real MTi does.
"""

from __future__ import annotations

import inspect
from typing import Any

from devices.errors import DeviceInitError
from devices.imu.driver import XbusImu


class EmulatedImu(XbusImu):
    """The mock backend: the Xbus driver against an ImuEmulator on a pty it owns."""

    backend = "mock"

    def __init__(self, rate_hz: int = 100, baudrate: int = 115200, **kw: Any) -> None:
        """`kw`: the emulator's parameters (ImuEmulator: drift_ppm, jitter_ms, seed,
        orientation_at, noise, model, settings_write_s, ...) and the driver's (XbusImu:
        outputs, raw_sink, ...), each given to its owner by name."""
        from devices.imu.emulator import ImuEmulator

        emulated = inspect.signature(ImuEmulator).parameters
        emulator = {k: kw.pop(k) for k in list(kw) if k in emulated}
        try:
            self.emulator = ImuEmulator(rate_hz=rate_hz, baudrate=baudrate, **emulator)
        except ValueError as e:
            raise DeviceInitError(str(e)) from None
        port = self.emulator.start()
        try:
            super().__init__(port, baudrate, rate_hz, **kw)
        except BaseException:
            self.emulator.stop()
            raise

    @classmethod
    def from_config(cls, config: Any, orientation_at=None) -> EmulatedImu:
        return cls(
            rate_hz=getattr(config, "rate_hz", 100),
            drift_ppm=getattr(config, "drift_ppm", 0.0),
            jitter_ms=getattr(config, "jitter_ms", 0.0),
            seed=getattr(config, "seed", 0),
            orientation_at=orientation_at,
            baudrate=getattr(config, "baudrate", 115200),
            model=getattr(config, "emulate", "MTi-3"),
        )

    def true_time_ns(self, sample_time_fine: int) -> int:
        """When the emulator really took that sample (for sync-accuracy checks)."""
        return self.emulator.true_time_ns(sample_time_fine)

    def inject(self, fault: str, **kw) -> None:
        """A fault of the emulated device (see ImuEmulator.inject)."""
        self.emulator.inject(fault, **kw)

    def close(self) -> None:
        super().close()
        self.emulator.stop()
