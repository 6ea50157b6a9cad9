"""What an emulated MTi measures: its clock, and each sample's MTData2 payload.

Its orientation comes from `orientation_at(t)` (seconds since start -> [w, x, y, z],
sensor -> world (ENU)): the simulated walk's thigh when the mock camera runs, else a
simple gait-like swing. Acceleration is gravity in the sensor frame, rate of turn the
orientation's derivative, both with noise and bias; an attitude filter's error
(devices/orientation_error.py) may be added to the orientation it reports.
"""

from __future__ import annotations

import dataclasses
import datetime
from collections.abc import Callable

import numpy as np

from devices import xbus
from devices.orientation_error import OrientationError, OrientationErrorModel
from devices.rotations import (
    matrix_to_quat,
    quat_conjugate,
    quat_from_euler,
    quat_multiply,
    quat_normalize,
    quat_to_euler,
    quat_to_matrix,
)

GRAVITY = 9.81  # m/s^2
MAGNETIC_FIELD_ENU = np.array([0.0, 0.42, -0.91])  # arbitrary units: north and down


def gait_orientation(t: float) -> np.ndarray:
    """A thigh swinging at 0.9 Hz: pitch about -5 +- 25 degrees, a little roll."""
    phase = 2 * np.pi * 0.9 * t
    flexion = np.radians(5.0 + 25.0 * np.sin(phase) + 3.0 * np.sin(2 * phase))
    roll = np.radians(2.0 * np.sin(phase))
    return quat_from_euler(roll, -flexion, 0.0)


@dataclasses.dataclass(frozen=True)
class EmulatorClock:
    """The emulator's device clock against the session clock (10 kHz ticks, drifting).

    A value, so the host can check sync against it from another process (the mock rig).
    """

    t0_ns: int  # session time at ...
    epoch_ticks: int  # ... which the device clock read this many ticks
    drift_ppm: float

    def ticks_at(self, t_ns: int) -> float:
        """Device clock (SampleTimeFine ticks, unwrapped) at a session time."""
        return self.epoch_ticks + (t_ns - self.t0_ns) * (1 + self.drift_ppm * 1e-6) / 1e5

    def time_of_ticks(self, ticks: float) -> int:
        return self.t0_ns + round((ticks - self.epoch_ticks) * 1e5 / (1 + self.drift_ppm * 1e-6))

    def true_time_ns(self, sample_time_fine: int, now: int) -> int:
        """When the sample stamped sample_time_fine (wrapping) was taken, seen at `now`."""
        wraps = round((self.ticks_at(now) - sample_time_fine) / 2**32)
        return self.time_of_ticks(sample_time_fine + wraps * 2**32)


class Motion:
    """The sensor's physics and its filter: the values of each output at a sample."""

    def __init__(
        self,
        orientation_at: Callable[[float], np.ndarray],
        rng: np.random.Generator,
        noise: bool,
        orientation_error: OrientationErrorModel | None,
        gnss: bool,
    ) -> None:
        self.orientation_at = orientation_at
        self._rng = rng  # the emulator's own: one seed draws everything
        self.noise = noise
        self._gyro_bias = rng.normal(0.0, 0.003, 3) if noise else np.zeros(3)
        self._accel_bias = rng.normal(0.0, 0.02, 3) if noise else np.zeros(3)
        # The attitude filter's error (devices.orientation_error); none: the true orientation.
        self._filter_error = OrientationError(orientation_error, rng) if orientation_error else None
        self._gnss = gnss  # a GNSS receiver gives a valid UTC

    def mtdata2(
        self,
        outputs: list[xbus.OutputSetting],
        rate: int,
        index: int,
        counter: int,
        ticks: int,
        t: float,
        utc_ns: int,
    ) -> bytes:
        """The payload of sample `index` (of messages at `rate`), taken `t` s after start."""
        dt = 1.0 / rate
        q = quat_normalize(np.asarray(self.orientation_at(t), dtype=np.float64))
        rot = quat_to_matrix(q)
        rng = self._rng
        noisy = self.noise

        def noise(sigma: float, n: int = 3) -> np.ndarray:
            return rng.normal(0.0, sigma, n) if noisy else np.zeros(n)

        accel = rot.T @ np.array([0.0, 0.0, GRAVITY]) + self._accel_bias + noise(0.03)
        h = 0.002  # body rate from the orientation's central difference
        q_a = quat_normalize(np.asarray(self.orientation_at(t - h), dtype=np.float64))
        q_b = quat_normalize(np.asarray(self.orientation_at(t + h), dtype=np.float64))
        dq = quat_multiply(quat_conjugate(q_a), q_b)
        if dq[0] < 0:
            dq = -dq
        gyro = dq[1:] / h + self._gyro_bias + noise(0.004)  # 2 * vec / (2 h)
        field_enu = rot.T @ MAGNETIC_FIELD_ENU  # physics sees the true orientation
        if self._filter_error is not None:  # the filter's estimate, not the truth
            q = self._filter_error.apply(q, t)
            rot = quat_to_matrix(q)
        values: dict[str, object] = {}
        encodings: dict[str, tuple[int, str]] = {}  # name -> (precision, coordinate system)
        for setting in outputs:
            name = setting.name
            if setting.rate_hz == 0:
                continue
            if setting.rate_hz != xbus.EVERY_PACKET and index % max(1, rate // setting.rate_hz):
                continue
            system = xbus.COORDINATE_SYSTEMS.get(setting.xdi & 0xC, "ENU")
            encodings[name] = (setting.xdi & 0x3, system)
            to_frame = np.array(xbus.FRAME_FROM_ENU[system], dtype=np.float64)
            if name == "packet_counter":
                values[name] = counter
            elif name == "sample_time_fine":
                values[name] = ticks % 2**32
            elif name == "sample_time_coarse":
                values[name] = (ticks // 10_000) % 2**32
            elif name == "utc_time":
                values[name] = self._utc_time(utc_ns)
            elif name == "status_word":
                values[name] = 0b11  # self-test ok, filter valid
            elif name == "quaternion":
                values[name] = tuple(quat_multiply(matrix_to_quat(to_frame), q))
            elif name == "rotation_matrix":
                values[name] = tuple(map(tuple, to_frame @ rot))
            elif name == "euler":
                values[name] = tuple(np.degrees(quat_to_euler(matrix_to_quat(to_frame @ rot))))
            elif name == "acceleration":
                values[name] = tuple(accel)
            elif name == "free_acceleration":
                values[name] = tuple(
                    to_frame @ (rot @ (accel - self._accel_bias) - [0.0, 0.0, GRAVITY])
                )
            elif name == "delta_v":
                values[name] = tuple(accel * dt)
            elif name == "rate_of_turn":
                values[name] = tuple(gyro)
            elif name == "delta_q":
                q_prev = quat_normalize(np.asarray(self.orientation_at(t - dt), dtype=np.float64))
                d = quat_multiply(quat_conjugate(q_prev), q)
                values[name] = tuple(d if d[0] >= 0 else -d)
            elif name == "magnetic_field":
                values[name] = tuple(field_enu + noise(0.01))
            elif name == "temperature":
                values[name] = 31.0 + float(noise(0.05, 1)[0])
            elif name == "baro_pressure":
                values[name] = int(101325 + noise(2.0, 1)[0])
        return b"".join(
            xbus.encode_packet(name, value, *encodings[name]) for name, value in values.items()
        )

    def _utc_time(self, ns: int) -> tuple[int, ...]:
        """UtcTime of a sample at UTC `ns`. Without a GNSS receiver a device has no valid
        UTC: flags 0 (0x07 on a GNSS model)."""
        when = datetime.datetime.fromtimestamp(ns // 1_000_000_000, datetime.UTC)
        flags = 0x07 if self._gnss else 0x00
        fields = (when.year, when.month, when.day, when.hour, when.minute, when.second)
        return (ns % 1_000_000_000, *fields, flags)
