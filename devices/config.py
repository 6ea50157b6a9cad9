"""The devices' configuration sections: [camera], [simulator], [imu], [mounting].

capture.config composes every package's sections into the one TOML file and validates
each key by the type of its field here, then by its range: each section's `problems()`
lists the keys whose values are out of range, with the valid range.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from devices.xbus import BAUD_CODES

MAX_FPS = 45.0  # the pico flexx's fastest use case; the mock camera stands in for it
Problems = list[tuple[str, str]]  # (key, what the valid values are)


def number_in(
    value: float, low: float | None = None, high: float | None = None, *, low_open: bool = False
) -> bool:
    """A finite number within [low, high] (or (low, high] with low_open)."""
    if not isinstance(value, (int, float)) or not math.isfinite(value):
        return False
    if low is not None and (value <= low if low_open else value < low):
        return False
    return high is None or value <= high


def one_of(key: str, value: str, allowed: tuple[str, ...]) -> Problems:
    return [] if value in allowed else [(key, "one of " + " | ".join(allowed))]


@dataclass
class CameraConfig:
    backend: str = "mock"  # mock | royale | replay
    fps: float = 15.0  # the paper ran at 15 fps
    use_case: str = ""  # royale use case name; empty: the one matching fps
    camera_id: str = ""  # royale camera id or .rrf file; empty: the first camera
    buffer_frames: int = 8
    # Silent this long (s): "lost", and reopened until frames come (a stall before it).
    lost_after_s: float = 5.0

    def problems(self) -> Problems:
        out = one_of("backend", self.backend, ("mock", "royale", "replay"))
        if not number_in(self.fps, 0.0, MAX_FPS, low_open=True):
            out.append(("fps", f"a frame rate 0 < fps <= {MAX_FPS:g} (the pico flexx's modes)"))
        if not 1 <= self.buffer_frames <= 1000:
            out.append(("buffer_frames", "1 to 1000"))
        if not number_in(self.lost_after_s, 0.5, 600.0):
            out.append(("lost_after_s", "0.5 to 600 seconds"))
        return out


@dataclass
class SimulatorConfig:
    course: str = "indoor"  # indoor | outdoor
    seed: int = 0
    speed_mps: float = 1.1
    cadence_spm: float = 105.0  # steps per minute
    camera_height_m: float = 0.55  # thigh mount height when standing
    camera_tilt_deg: float = 35.0  # downward tilt relative to the thigh
    realtime: bool = True
    stand: bool = False  # the walker stands still at the start (calibration on mock devices)
    loop: bool = False  # walk the course again at its end (the UI loops; `record` stops)
    # Real time: camera renderer and IMU emulator in a child process, costing the session's
    # threads nothing, as real sensors would (devices/simulator/rig.py)
    process: bool = True

    def problems(self) -> Problems:
        out = one_of("course", self.course, ("indoor", "outdoor"))
        for key, low, high in (
            ("speed_mps", 0.1, 5.0),  # slower than a slow walk never reaches the course's end
            ("cadence_spm", 0.0, 300.0),
            ("camera_height_m", 0.0, 3.0),
        ):
            if not number_in(getattr(self, key), low, high, low_open=True):
                out.append((key, f"{low:g} < {key} <= {high:g}"))
        if not number_in(self.camera_tilt_deg, -90.0, 90.0):
            out.append(("camera_tilt_deg", "-90 to 90 degrees"))
        if not isinstance(self.seed, int) or not 0 <= self.seed <= SEED_MAX:
            out.append(("seed", f"an integer from 0 to {SEED_MAX}"))
        return out


SEED_MAX = 2**32 - 1  # numpy's seed sequence takes no negative number


@dataclass
class ImuConfig:
    backend: str = "mock"  # mock (emulator on a pseudo-terminal) | serial
    port: str = ""  # e.g. /dev/ttyUSB0 for backend = serial
    baudrate: int = 115200
    rate_hz: int = 100
    drift_ppm: float = 50.0  # emulator only
    jitter_ms: float = 2.0  # emulator only
    # The model the mock backend plays (devices/imu/family.py): "MTi-3" (AHRS, 1-series,
    # 100 Hz at most), "MTi-1" (IMU only), "MTi-630" (600-series, 400 Hz), ...
    emulate: str = "MTi-3"

    def problems(self) -> Problems:
        out = one_of("backend", self.backend, ("mock", "serial"))
        if self.baudrate not in BAUD_CODES.values():
            rates = ", ".join(str(b) for b in sorted(set(BAUD_CODES.values())))
            out.append(("baudrate", f"one of the Xsens baud rates: {rates}"))
        if not 1 <= self.rate_hz <= 2000:
            out.append(("rate_hz", "1 to 2000 Hz"))
        if not number_in(self.drift_ppm, -10_000.0, 10_000.0):
            out.append(("drift_ppm", "-10000 to 10000 ppm"))
        if not number_in(self.jitter_ms, 0.0, 1000.0):
            out.append(("jitter_ms", "0 to 1000 ms"))
        return out


@dataclass
class MountingConfig:
    """Camera orientation relative to the IMU, on top of the nominal axes.

    Nominal: camera z (forward) along IMU x, camera x (right) along IMU -y. `pitch_deg`
    tilts the camera down, `roll_deg` about its optical axis. Written by `walkcap calibrate`.
    """

    roll_deg: float = 0.0
    pitch_deg: float = 35.0
    yaw_deg: float = 0.0

    def problems(self) -> Problems:
        return [
            (key, "a finite angle, -180 to 180 degrees")
            for key in ("roll_deg", "pitch_deg", "yaw_deg")
            if not number_in(getattr(self, key), -180.0, 180.0)
        ]


# One line per key for `walkcap config` (capture.config.documented); every field has one.
DOCS: dict[type, dict[str, str]] = {
    CameraConfig: {
        "backend": "camera backend: mock (simulated walk) | royale (pmd pico flexx) | replay",
        "fps": "frame rate, frames per second (the paper: 15)",
        "use_case": "royale use case name; empty: the one matching fps",
        "camera_id": "royale camera serial or .rrf file (replay: the .mcap); empty: the first one",
        "buffer_frames": "frames buffered for the pipeline before the oldest is dropped",
        "lost_after_s": "seconds without a frame before the camera is lost and reopened",
    },
    SimulatorConfig: {
        "course": "mock walk preset: indoor | outdoor",
        "seed": "mock walk seed (the same seed walks the same course)",
        "speed_mps": "mock walking speed, metres per second",
        "cadence_spm": "mock cadence, steps per minute",
        "camera_height_m": "mock camera height on the thigh when standing, metres",
        "camera_tilt_deg": "mock camera tilt down relative to the thigh, degrees",
        "realtime": "mock devices deliver in real time (false: as fast as the pipeline runs)",
        "stand": "the mock walker stands still at the start (calibration on mock devices)",
        "loop": "walk the mock course again at its end (the UI and `record --duration` loop)",
        "process": "real-time mock devices run in a child process, as hardware runs outside",
    },
    ImuConfig: {
        "backend": "IMU backend: mock (emulator on a pseudo-terminal) | serial (Xsens MTi)",
        "port": "IMU serial port for backend serial, e.g. /dev/ttyUSB0",
        "baudrate": "IMU line speed: the device's (walkcap imu set-baud changes it)",
        "rate_hz": "IMU output rate, samples per second; fitted to the model (1-series: 100 Hz)",
        "drift_ppm": "mock IMU clock drift against the host, parts per million",
        "jitter_ms": "mock IMU transmit jitter, milliseconds",
        "emulate": "mock IMU model it plays (MTi-1, MTi-630, ...); above 100 Hz a 600-series",
    },
    MountingConfig: {
        "roll_deg": "camera roll about its optical axis relative to the IMU, degrees",
        "pitch_deg": "camera pitch down relative to the IMU, degrees (walkcap calibrate)",
        "yaw_deg": "camera yaw relative to the IMU, degrees (not observable from a floor)",
    },
}
