"""The mock IMU backend: the real Xbus driver against an `ImuEmulator` on a pty it owns.

The mock exercises the same driver, pyserial and termios as a real MTi does.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from devices.errors import DeviceInitError
from devices.imu.driver import XbusImu


class EmulatedImu(XbusImu):
    """The mock backend: the Xbus driver against an ImuEmulator on a pty it owns."""

    backend = "mock"

    def __init__(
        self,
        rate_hz: int = 100,
        drift_ppm: float = 0.0,
        jitter_ms: float = 0.0,
        seed: int = 0,
        orientation_at: Callable[[float], np.ndarray] | None = None,
        noise: bool = True,
        baudrate: int = 115200,
        model: str = "MTi-3",
        settings_write_s: float | None = None,
        **driver: Any,
    ) -> None:
        from devices.imu.emulator import ImuEmulator

        try:
            self.emulator = ImuEmulator(
                rate_hz=rate_hz,
                drift_ppm=drift_ppm,
                jitter_ms=jitter_ms,
                seed=seed,
                orientation_at=orientation_at,
                noise=noise,
                baudrate=baudrate,
                model=model,
                settings_write_s=settings_write_s,
            )
        except ValueError as e:
            raise DeviceInitError(str(e)) from None
        port = self.emulator.start()
        try:
            super().__init__(port, baudrate, rate_hz, **driver)
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
