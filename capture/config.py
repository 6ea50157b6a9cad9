"""walkcap configuration: one TOML file, defaults that run out of the box, flags on top.

Where it is read from: `--config PATH`, else `$WALKCAP_CONFIG`, else `./walkcap.toml` when
it exists, else the defaults. An unknown key or a value of the wrong type is a
ConfigError naming the key (`camera.fps: expected a number, got "fast"`).
Sections extend by adding a field to their dataclass below: the loader validates by type.
"""

from __future__ import annotations

import dataclasses
import os
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from capture.errors import ConfigError
from inference.fusion import PAPER_TRANSITION  # the authors' matrix, defined once

DEFAULT_PATH = Path("walkcap.toml")


@dataclass
class SessionConfig:
    recordings: str = "recordings"  # output folder
    operator: str = ""
    # The pipeline thread's SCHED_FIFO priority (1-99; 0: normal scheduling), where the
    # system allows it (root, CAP_SYS_NICE or an rtprio limit); otherwise it runs normally.
    realtime_priority: int = 10


@dataclass
class CameraConfig:
    backend: str = "mock"  # mock | royale | replay
    fps: float = 15.0  # the paper ran at 15 fps
    use_case: str = ""  # royale use case name; empty: the one matching fps
    camera_id: str = ""  # royale camera id or .rrf file; empty: the first camera
    buffer_frames: int = 8


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


@dataclass
class ImuConfig:
    backend: str = "mock"  # mock (emulator on a pseudo-terminal) | serial
    port: str = ""  # e.g. /dev/ttyUSB0 for backend = serial
    baudrate: int = 115200
    rate_hz: int = 100
    drift_ppm: float = 50.0  # emulator only
    jitter_ms: float = 2.0  # emulator only


@dataclass
class MountingConfig:
    """Camera orientation relative to the IMU, on top of the nominal axes.

    Nominal: camera z (forward) along IMU x, camera x (right) along IMU -y. `pitch_deg`
    tilts the camera down, `roll_deg` about its optical axis. Written by `walkcap calibrate`.
    """

    roll_deg: float = 0.0
    pitch_deg: float = 35.0
    yaw_deg: float = 0.0


@dataclass
class PreprocessConfig:
    corridor_width_m: float = 0.1  # across the walking direction (authors: 0.1 m)
    min_forward_m: float = 0.0
    max_forward_m: float = 2.5  # see inference.preprocess.PreprocessParams
    grid_size: int = 100  # 100 x 100 cells
    cell_m: float = 0.01  # 1 cm cells
    min_confidence: int = 1
    outlier_min_points: int = 4  # isolated-point removal, 3 x 3 cm neighbourhood (0: off)
    max_elevation_deg: float = 30.0  # camera looking higher than this: no image
    backend: str = "numpy"  # numpy | open3d (same result; numpy is faster)


@dataclass
class ModelConfig:
    path: str = ""  # empty: the bundled model
    device: str = "auto"  # auto | cpu | cuda


@dataclass
class FusionConfig:
    window: int = 5  # l_w, smoothing window (frames)
    vote_delay: int = 1  # l_v, voting half-window (frames)
    transition: list[list[float]] = field(default_factory=lambda: PAPER_TRANSITION.tolist())


@dataclass
class KeysConfig:
    mode_lg: str = "1"
    mode_us: str = "2"
    mode_ds: str = "3"
    mode_ur: str = "4"
    mode_dr: str = "5"
    undo: str = "u"
    marker: str = "m"
    record: str = "r"
    freeze: str = "space"
    help: str = "question_mark"
    quit: str = "q"


@dataclass
class Config:
    session: SessionConfig = field(default_factory=SessionConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    simulator: SimulatorConfig = field(default_factory=SimulatorConfig)
    imu: ImuConfig = field(default_factory=ImuConfig)
    mounting: MountingConfig = field(default_factory=MountingConfig)
    preprocess: PreprocessConfig = field(default_factory=PreprocessConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    keys: KeysConfig = field(default_factory=KeysConfig)
    source: str = ""  # the file it was read from, empty for defaults


def _type_name(tp: Any) -> str:
    return {int: "an integer", float: "a number", str: "a string", bool: "true or false"}.get(
        tp, getattr(tp, "__name__", str(tp))
    )


def _convert(value: Any, tp: Any, key: str) -> Any:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        return _convert(value, args[0], key)
    if origin is list:
        (item,) = typing.get_args(tp)
        if not isinstance(value, list):
            raise ConfigError(f"{key}: expected a list, got {value!r}")
        return [_convert(v, item, f"{key}[{i}]") for i, v in enumerate(value)]
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"{key}: expected a table [{key}], got {value!r}")
        return _build(tp, value, key)
    if tp is bool:
        if isinstance(value, bool):
            return value
    elif tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
    elif tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif tp is str:
        if isinstance(value, str):
            return value
    raise ConfigError(f"{key}: expected {_type_name(tp)}, got {value!r}")


def _build(cls: type, table: dict, prefix: str = "") -> Any:
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    kwargs = {}
    for key, value in table.items():
        full = f"{prefix}.{key}" if prefix else key
        if key not in names or key == "source":
            known = ", ".join(sorted(n for n in names if n != "source"))
            raise ConfigError(f"unknown key {full!r} (known here: {known})")
        kwargs[key] = _convert(value, hints[key], full)
    return cls(**kwargs)


def from_dict(table: dict) -> Config:
    return _build(Config, table)


def to_dict(config: Config) -> dict:
    data = dataclasses.asdict(config)
    data.pop("source", None)
    return data


def find_path(explicit: str | os.PathLike | None = None) -> Path | None:
    """The file to read: explicit, else $WALKCAP_CONFIG, else ./walkcap.toml if present."""
    if explicit:
        return Path(explicit)
    env = os.environ.get("WALKCAP_CONFIG")
    if env:
        return Path(env)
    return DEFAULT_PATH if DEFAULT_PATH.exists() else None


def load(path: str | os.PathLike | None = None) -> Config:
    """Read and validate the configuration; defaults when there is no file."""
    found = find_path(path)
    if found is None:
        return Config()
    try:
        with open(found, "rb") as f:
            table = tomllib.load(f)
    except FileNotFoundError:
        raise ConfigError(f"configuration file not found: {found}") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{found}: not valid TOML: {e}") from None
    except OSError as e:
        raise ConfigError(f"cannot read configuration {found}: {e.strerror}") from None
    try:
        config = from_dict(table)
    except ConfigError as e:
        raise ConfigError(f"{found}: {e}") from None
    config.source = str(found)
    return config


def override(config: Config, dotted: str, value: Any) -> None:
    """Set `section.key` from a command-line flag, with the same type checks."""
    section_name, _, key = dotted.partition(".")
    section = getattr(config, section_name)
    hints = typing.get_type_hints(type(section))
    if key not in hints:
        raise ConfigError(f"unknown key {dotted!r}")
    setattr(section, key, _convert(value, hints[key], dotted))


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(value)


def dumps(config: Config) -> str:
    """The configuration as TOML (every key, so a saved file documents itself)."""
    lines = []
    for section, table in to_dict(config).items():
        lines.append(f"[{section}]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in table.items()]
        lines.append("")
    return "\n".join(lines)


def save(config: Config, path: str | os.PathLike) -> Path:
    """Write the whole configuration atomically (a crash never leaves half a file)."""
    path = Path(path)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(dumps(config))
    os.replace(tmp, path)
    return path
