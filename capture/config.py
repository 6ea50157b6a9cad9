"""walkcap configuration: one TOML file, defaults that run out of the box, flags on top.

Where it is read from: `--config PATH`, else `$WALKCAP_CONFIG`, else `./walkcap.toml` when
it exists, else the defaults. An unknown key, a value of the wrong type or out of its range
is a ConfigError naming the key (`camera.fps: expected a number, got "fast"`; `camera.fps
= 0.0: expected a frame rate 0 < fps <= 45 (the pico flexx's modes)`), before any device
opens. Ranges are each section's `problems()`.
Each package owns its sections (devices.config, inference.config, the session's and the
keys' here); `Config` composes them. A section extends by adding a field to its dataclass:
the loader validates by type.
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
from devices.config import DOCS as DEVICE_DOCS
from devices.config import CameraConfig, ImuConfig, MountingConfig, SimulatorConfig
from devices.files import check_replaceable
from inference.config import DOCS as INFERENCE_DOCS
from inference.config import FusionConfig, ModelConfig, PreprocessConfig

DEFAULT_PATH = Path("walkcap.toml")


@dataclass
class SessionConfig:
    recordings: str = "recordings"  # output folder
    operator: str = ""
    # The pipeline thread's SCHED_FIFO priority (1-99; 0: normal scheduling), where the
    # system allows it (root, CAP_SYS_NICE or an rtprio limit); otherwise it runs normally.
    realtime_priority: int = 10

    def problems(self) -> list[tuple[str, str]]:
        out = [] if self.recordings else [("recordings", "a folder name")]
        if not 0 <= self.realtime_priority <= 99:
            out.append(("realtime_priority", "0 (normal scheduling) to 99"))
        return out


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
class LslConfig:
    """Lab Streaming Layer: walkcap's streams out, other devices' streams into the recording."""

    enabled: bool = False  # outlets: IMU, classifier and decisions, labels and markers
    record: list[str] = field(default_factory=list)  # LSL stream names to record, e.g. ["EMG"]
    # LabRecorder-compatible remote control (start, stop, filename) on localhost
    remote_control: bool = False
    remote_port: int = 22345  # LabRecorder's default
    # a remote `filename {root:DIR}` outside the recordings folder: refused unless allowed
    remote_any_root: bool = False
    # when set, each remote-control connection's first line is `token <this>`
    remote_token: str = ""


@dataclass
class FoxgloveConfig:
    """A live Foxglove WebSocket server with the recording's topics and schemas."""

    enabled: bool = False
    host: str = "127.0.0.1"  # localhost only unless asked otherwise
    port: int = 8765  # Foxglove's default
    # depth, images and clouds at most this often (live view only): encoding them shares the
    # pipeline's interpreter, and 5 a second keeps the live view within 1 ms of its latency
    image_hz: float = 5.0


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
    lsl: LslConfig = field(default_factory=LslConfig)
    foxglove: FoxgloveConfig = field(default_factory=FoxgloveConfig)
    source: str = ""  # the file it was read from, empty for defaults


_KEY_DOC = "key for {}"  # Textual key names: 1, u, space, question_mark, ctrl+x, ...
# One line per key for `walkcap config`; the devices' and algorithms' come from their packages.
DOCS: dict[type, dict[str, str]] = {
    SessionConfig: {
        "recordings": "folder the recordings are written to (created when missing)",
        "operator": "who runs the session, written into every recording",
        "realtime_priority": "pipeline thread SCHED_FIFO priority 1-99 where allowed; 0: normal",
    },
    KeysConfig: {
        "mode_lg": _KEY_DOC.format("the true mode LG (level ground)"),
        "mode_us": _KEY_DOC.format("the true mode US (stairs up)"),
        "mode_ds": _KEY_DOC.format("the true mode DS (stairs down)"),
        "mode_ur": _KEY_DOC.format("the true mode UR (ramp up)"),
        "mode_dr": _KEY_DOC.format("the true mode DR (ramp down)"),
        "undo": _KEY_DOC.format("undoing the last label change"),
        "marker": _KEY_DOC.format("a marker with an optional note"),
        "record": _KEY_DOC.format("starting / stopping a trial"),
        "freeze": _KEY_DOC.format("freezing the display"),
        "help": _KEY_DOC.format("the help screen"),
        "quit": _KEY_DOC.format("quitting (ctrl+q always quits too)"),
    },
    LslConfig: {
        "enabled": "LSL outlets: walkcap IMU, walkcap Terrain, walkcap Markers",
        "record": "names of other devices' LSL streams recorded into each trial",
        "remote_control": "LabRecorder's start / stop / filename commands on 127.0.0.1",
        "remote_port": "the remote control's TCP port (LabRecorder's)",
        "remote_any_root": "let a remote {root:DIR} name any folder, not only one in recordings",
        "remote_token": "if set, a remote-control connection starts with the line `token <it>`",
    },
    FoxgloveConfig: {
        "enabled": "serve the live session's topics to Foxglove over a WebSocket",
        "host": "address the Foxglove server listens on (localhost only unless changed)",
        "port": "the Foxglove server's port",
        "image_hz": "depth, images and clouds sent at most this often, per second",
    },
    **DEVICE_DOCS,
    **INFERENCE_DOCS,
}


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
        if isinstance(value, str) and "\x00" in value:  # no path or name can hold one
            raise ConfigError(f"{key}: a NUL character is not allowed")
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
    built = cls(**kwargs)
    check_range(built, prefix)
    return built


def check_range(section: Any, name: str, flag: str = "") -> None:
    """ConfigError for the section's first key out of range, naming it (and the flag that
    set it) with the valid range."""
    problems = section.problems() if hasattr(section, "problems") else []
    if not problems:
        return
    key, valid = problems[0]
    value = getattr(section, key)
    shown = "a ragged or invalid matrix" if key == "transition" else repr(value)
    where = f"{flag} ({name}.{key})" if flag else f"{name}.{key}"
    raise ConfigError(f"{where} = {shown}: expected {valid}")


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
    except RecursionError:  # tomllib recurses once per nested table or array
        raise ConfigError(f"{found}: tables or arrays nested too deeply") from None
    except UnicodeDecodeError as e:  # TOML is UTF-8: a UTF-16 or Latin-1 file stops here
        raise ConfigError(
            f"{found}: not UTF-8 text (byte {e.start}); save it as UTF-8 without a BOM"
        ) from None
    except OSError as e:
        raise ConfigError(f"cannot read configuration {found}: {e.strerror}") from None
    try:
        config = from_dict(table)
    except ConfigError as e:
        raise ConfigError(f"{found}: {e}") from None
    config.source = str(found)
    return config


def override(config: Config, dotted: str, value: Any, flag: str = "") -> None:
    """Set `section.key` from a command-line flag, with the same type and range checks;
    the section is left as it was when the value is refused."""
    section_name, _, key = dotted.partition(".")
    section = getattr(config, section_name)
    hints = typing.get_type_hints(type(section))
    if key not in hints:
        raise ConfigError(f"unknown key {dotted!r}")
    old = getattr(section, key)
    setattr(section, key, _convert(value, hints[key], flag or dotted))
    try:
        check_range(section, section_name, flag)
    except ConfigError:
        setattr(section, key, old)
        raise


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


def documented(config: Config) -> str:
    """The configuration as TOML with a comment per key: what it is and its default.

    What `walkcap config` prints; it loads back as the same configuration.
    """
    defaults = to_dict(Config())
    lines = [
        "# walkcap configuration: every key with what it does and its default.",
        "# Save as walkcap.toml (or pass --config FILE); keys left out take their default.",
        "# [keys] take Textual key names: 1, u, space, question_mark, ctrl+x, ...",
        "",
    ]
    for f in dataclasses.fields(Config):
        if f.name == "source":
            continue
        section = getattr(config, f.name)
        docs = DOCS.get(type(section), {})
        lines.append(f"[{f.name}]")
        for key, value in dataclasses.asdict(section).items():
            default = _toml_value(defaults[f.name][key])
            if len(default) > 40:  # a matrix: `walkcap config --default` shows it in full
                default = "printed by --default"
            lines.append(f"# {docs.get(key, key)} [default: {default}]")
            if value and isinstance(value, list) and isinstance(value[0], list):
                rows = [f"    {_toml_value(row)}," for row in value]
                lines += [f"{key} = [", *rows, "]"]
            else:
                lines.append(f"{key} = {_toml_value(value)}")
        lines.append("")
    return "\n".join(lines)


def save(config: Config, path: str | os.PathLike) -> Path:
    """Write the whole configuration atomically (a crash never leaves half a file)."""
    path = check_replaceable(path)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(dumps(config))
    os.replace(tmp, path)
    return path
