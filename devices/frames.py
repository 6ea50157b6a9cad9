"""What devices produce: depth frames and IMU samples, on the session clock.

Conventions (every module relies on them):
- Times are integer nanoseconds. `host_time_ns` is the receive time on the session clock
  (`devices.clock.now_ns`); `time_ns` is the device's own sample time mapped onto the
  session clock (the best estimate of when the sample was taken).
- Camera frame (royale): x right, y down, z forward, metres.
- Quaternions are [w, x, y, z] and rotate vectors from the sensor frame into the world
  frame: world = R(q) @ sensor. World frame: x forward (walking direction at start),
  y left, z up (gravity is -z).
- IMU body frame on the thigh of a person standing upright: x forward, y left, z up.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

MODES = ("LG", "US", "DS", "UR", "DR")
MODE_NAMES = {
    "LG": "level ground",
    "US": "up stairs",
    "DS": "down stairs",
    "UR": "up ramp",
    "DR": "down ramp",
}
# One colour per mode on every screen and figure (the live UI, replay, `eval --plot`):
# distinct hues that stay apart on dark and light backgrounds and for the common
# colour-vision deficiencies; the letters always go with them, so no meaning rests on colour.
MODE_COLORS = {
    "LG": "#4caf50",  # green
    "US": "#2f7ff0",  # blue
    "DS": "#00b8c4",  # cyan
    "UR": "#f0a020",  # amber
    "DR": "#d048c8",  # magenta
}
# Gait events of the instrumented leg (the thigh that carries the IMU and the camera): the
# moments a prosthesis controller acts at. Heel contact starts a stance, toe off a swing.
GAIT_EVENTS = ("heel_contact", "toe_off")
GAIT_SOURCES = ("imu", "simulator")  # detected from the thigh IMU, or the simulator's truth


@dataclass(frozen=True)
class CameraGeometry:
    """The camera's static geometry: resolution, pinhole intrinsics, identity."""

    width: int = 224
    height: int = 171
    fx: float = 186.0
    fy: float = 206.0
    cx: float = 111.5
    cy: float = 85.0
    min_range_m: float = 0.1
    max_range_m: float = 4.0
    name: str = "pico flexx"
    serial: str = ""

    def rays(self) -> np.ndarray:
        """Unit ray direction per pixel, (height, width, 3) float32, camera frame."""
        u = (np.arange(self.width, dtype=np.float64) - self.cx) / self.fx
        v = (np.arange(self.height, dtype=np.float64) - self.cy) / self.fy
        uu, vv = np.meshgrid(u, v)
        d = np.stack([uu, vv, np.ones_like(uu)], axis=-1)
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        return d.astype(np.float32)


@dataclass(frozen=True, slots=True)
class GaitEvent:
    """A heel contact or toe off of the instrumented leg, at `time_ns` on the session clock
    (the device's clock mapped, as ImuSample.time_ns). `source`: "imu" (the detector,
    inference.gait) or "simulator" (the walk's truth); `mode`: the MODES name of the
    terrain under that foot, where known (the simulator knows it; the detector does not)."""

    time_ns: int
    event: str  # one of GAIT_EVENTS
    source: str  # one of GAIT_SOURCES
    mode: str | None = None


@dataclass
class DepthFrame:
    """One depth image. Invalid pixels have confidence 0 and xyz 0 (as royale gives them)."""

    index: int  # frame number since the camera started
    device_time_ns: int  # the camera's own timestamp
    host_time_ns: int  # receive time, session clock
    xyz: np.ndarray  # (height, width, 3) float32, metres, camera frame
    confidence: np.ndarray  # (height, width) uint8, 0 = invalid
    gray: np.ndarray  # (height, width) uint16 amplitude
    geometry: CameraGeometry = field(default_factory=CameraGeometry)
    truth: dict | None = None  # simulator only: {"mode": "LG", "pose": 4x4 list, ...}
    range_mm: np.ndarray | None = None  # read from a recording: its depth, rewritten as is


@dataclass
class ImuSample:
    """One IMU measurement (one MTData2 message); absent outputs are None."""

    host_time_ns: int  # receive time, session clock
    time_ns: int | None = None  # device sample time mapped onto the session clock
    packet_counter: int | None = None
    sample_time_fine: int | None = None  # 10 kHz device ticks, wraps at 2**32
    quaternion: np.ndarray | None = None  # [w, x, y, z], sensor -> world
    acceleration: np.ndarray | None = None  # m/s^2, sensor frame
    rate_of_turn: np.ndarray | None = None  # rad/s, sensor frame
    status_word: int | None = None
    extra: dict = field(default_factory=dict)  # other decoded MTData2 outputs
