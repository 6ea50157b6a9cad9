"""The devices' configuration sections: [camera], [simulator], [imu], [mounting].

capture.config composes every package's sections into the one TOML file and validates
each key by the type of its field here, then by its range: each section's `problems()`
lists the keys whose values are out of range, with the valid range.

Each key is a field made by `key()`: its default, what it does (the one line `walkcap
config` prints and docs/configuration.md shows) and, for a name out of a registry, where
the names are ("module:NAME", read when checked: a registry fills as higher layers import).
"""

from __future__ import annotations

import dataclasses
import importlib
import math
from dataclasses import dataclass
from typing import Any

from devices.xbus import BAUD_CODES

MAX_FPS = 45.0  # the pico flexx's fastest use case; the mock camera stands in for it
Problems = list[tuple[str, str]]  # (key, what the valid values are)


def key(
    default: Any = dataclasses.MISSING,
    doc: str = "",
    *,
    factory: Any = dataclasses.MISSING,
    choices: str | tuple[str, ...] | None = None,
    secret: bool = False,
) -> Any:
    """A configuration key: a dataclass field with its one-line `doc` and, for a key that
    names one of a set, its `choices` (names, or "module:NAME" of a registry). A `secret`
    key (a password, a token) stays out of the copies of the configuration that recordings
    carry."""
    metadata: dict[str, Any] = {"doc": doc}
    if choices is not None:
        metadata["choices"] = choices
    if secret:
        metadata["secret"] = True
    return dataclasses.field(default=default, default_factory=factory, metadata=metadata)


def doc_of(f: dataclasses.Field) -> str:
    return f.metadata.get("doc", "")


def choices_of(f: dataclasses.Field) -> tuple[str, ...] | None:
    """The names a key takes, read from its registry now; None for a free value."""
    choices = f.metadata.get("choices")
    if isinstance(choices, str):
        module, _, name = choices.partition(":")
        choices = getattr(importlib.import_module(module), name)
    return None if choices is None else tuple(choices)


def choice_problems(section: Any) -> Problems:
    """The keys of a section whose value is not one of its choices."""
    out: Problems = []
    for f in dataclasses.fields(section):
        allowed = choices_of(f)
        if allowed is not None:
            out += one_of(f.name, getattr(section, f.name), allowed)
    return out


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
    """The depth camera."""

    backend: str = key(
        "mock",
        "camera backend: mock is the simulated walk, royale the pmd pico flexx",
        choices="devices.camera:BACKENDS",
    )
    fps: float = key(15.0, "frame rate, frames per second (the paper: 15)")
    use_case: str = key("", "royale use case name; empty: the one matching fps")
    camera_id: str = key(
        "", "royale camera serial or .rrf file (replay: the .mcap); empty: the first one"
    )
    buffer_frames: int = key(8, "frames buffered for the pipeline before the oldest is dropped")
    # a stall before it: silence shorter than this is reported, not reopened
    lost_after_s: float = key(5.0, "seconds without a frame before the camera is lost and reopened")

    def problems(self) -> Problems:
        out = choice_problems(self)
        if not number_in(self.fps, 0.0, MAX_FPS, low_open=True):
            out.append(("fps", f"a frame rate 0 < fps <= {MAX_FPS:g} (the pico flexx's modes)"))
        if not 1 <= self.buffer_frames <= 1000:
            out.append(("buffer_frames", "1 to 1000"))
        if not number_in(self.lost_after_s, 0.5, 600.0):
            out.append(("lost_after_s", "0.5 to 600 seconds"))
        return out


@dataclass
class SimulatorConfig:
    """The mock devices' simulated walk (camera backend mock, IMU backend mock)."""

    course: str = key("indoor", "mock walk preset", choices="devices.simulator.course:PRESETS")
    seed: int = key(0, "mock walk seed (the same seed walks the same course)")
    speed_mps: float = key(1.1, "mock walking speed, metres per second")
    cadence_spm: float = key(105.0, "mock cadence, steps per minute")
    camera_height_m: float = key(0.55, "mock camera height on the thigh when standing, metres")
    camera_tilt_deg: float = key(35.0, "mock camera tilt down relative to the thigh, degrees")
    realtime: bool = key(
        True, "mock devices deliver in real time (false: as fast as the pipeline runs)"
    )
    stand: bool = key(
        False, "the mock walker stands still at the start (calibration on mock devices)"
    )
    loop: bool = key(
        False, "walk the mock course again at its end (the UI and `record --duration` loop)"
    )
    # the renderer and the emulator then cost the session's threads nothing
    # (devices/simulator/rig.py)
    process: bool = key(
        True, "real-time mock devices run in a child process, as hardware runs outside"
    )

    def problems(self) -> Problems:
        out = choice_problems(self)
        for name, low, high in (
            ("speed_mps", 0.1, 5.0),  # slower than a slow walk never reaches the course's end
            ("cadence_spm", 0.0, 300.0),
            ("camera_height_m", 0.0, 3.0),
        ):
            if not number_in(getattr(self, name), low, high, low_open=True):
                out.append((name, f"{low:g} < {name} <= {high:g}"))
        if not number_in(self.camera_tilt_deg, -90.0, 90.0):
            out.append(("camera_tilt_deg", "-90 to 90 degrees"))
        if not isinstance(self.seed, int) or not 0 <= self.seed <= SEED_MAX:
            out.append(("seed", f"an integer from 0 to {SEED_MAX}"))
        return out


SEED_MAX = 2**32 - 1  # numpy's seed sequence takes no negative number


@dataclass
class ImuConfig:
    """The thigh IMU (an Xsens MTi over Xbus)."""

    backend: str = key(
        "mock",
        "IMU backend: mock is an emulated MTi on a pseudo-terminal, serial an Xsens MTi",
        choices="devices.imu:BACKENDS",
    )
    port: str = key("", "IMU serial port for backend serial, e.g. /dev/ttyUSB0")
    baudrate: int = key(115200, "IMU line speed: the device's (walkcap imu set-baud changes it)")
    rate_hz: int = key(
        100, "IMU output rate, samples per second; fitted to the model (1-series: 100 Hz)"
    )
    drift_ppm: float = key(50.0, "mock IMU clock drift against the host, parts per million")
    jitter_ms: float = key(2.0, "mock IMU transmit jitter, milliseconds")
    # the models are devices/imu/family.py's: MTi-3 (AHRS, 1-series, 100 Hz at most),
    # MTi-1 (IMU only), MTi-630 (600-series, 400 Hz), ...
    emulate: str = key(
        "MTi-3", "mock IMU model it plays (MTi-1, MTi-630, ...); above 100 Hz a 600-series"
    )

    def problems(self) -> Problems:
        out = choice_problems(self)
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

    roll_deg: float = key(0.0, "camera roll about its optical axis relative to the IMU, degrees")
    pitch_deg: float = key(
        35.0, "camera pitch down relative to the IMU, degrees (walkcap calibrate)"
    )
    yaw_deg: float = key(
        0.0, "camera yaw relative to the IMU, degrees (not observable from a floor)"
    )

    def problems(self) -> Problems:
        return [
            (name, "a finite angle, -180 to 180 degrees")
            for name in ("roll_deg", "pitch_deg", "yaw_deg")
            if not number_in(getattr(self, name), -180.0, 180.0)
        ]
