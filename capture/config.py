"""walkcap configuration: one TOML file, defaults that run out of the box, flags on top.

Where it is read from: `--config PATH`, else `$WALKCAP_CONFIG`, else `./walkcap.toml` when
it exists, else the defaults. An unknown key, a value of the wrong type or out of its range
is a ConfigError naming the key (`camera.fps: expected a number, got "fast"`; `camera.fps
= 0.0: expected a frame rate 0 < fps <= 45 (the pico flexx's modes)`), before any device
opens. Ranges are each section's `problems()`.
Each package owns its sections (devices.config, inference.config, the session's and the
keys' here); `Config` composes them. A section extends by adding a field made by
`devices.config.key` (its default and its one line of doc): the loader validates it by type,
`walkcap config` and docs/configuration.md (`reference()`) show its doc.
"""

from __future__ import annotations

import dataclasses
import os
import re
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from capture.errors import ConfigError
from devices.config import (
    CameraConfig,
    ImuConfig,
    MountingConfig,
    SimulatorConfig,
    choice_problems,
    choices_of,
    doc_of,
    key,
)
from devices.files import check_replaceable
from inference.config import FusionConfig, ModelConfig, PreprocessConfig

DEFAULT_PATH = Path("walkcap.toml")


@dataclass
class SessionConfig:
    """Where the recordings go and how the session's pipeline thread runs."""

    recordings: str = key(
        "recordings", "folder the recordings are written to (created when missing)"
    )
    operator: str = key("", "who runs the session, written into every recording")
    subject_pattern: str = key(
        "^[A-Z]{1,4}[0-9]{1,4}$",
        "subject ids the form, `record` and `replay` accept (a regular expression the whole "
        "id must match): pseudonymous codes such as S01, never names",
    )
    remember_days: int = key(
        90,
        "days the form remembers a subject's body data after their last session "
        "(~/.config/walkcap/last_session.json); 0: not at all",
    )
    # SCHED_FIFO where the system allows it (root, CAP_SYS_NICE or an rtprio limit);
    # otherwise the thread runs normally
    realtime_priority: int = key(
        10, "pipeline thread SCHED_FIFO priority 1-99 where allowed; 0: normal"
    )

    def problems(self) -> list[tuple[str, str]]:
        out = [] if self.recordings else [("recordings", "a folder name")]
        if not 0 <= self.realtime_priority <= 99:
            out.append(("realtime_priority", "0 (normal scheduling) to 99"))
        if self.remember_days < 0:
            out.append(("remember_days", "0 (remember nothing) or more days"))
        try:
            re.compile(self.subject_pattern)
        except re.error as e:
            out.append(("subject_pattern", f"a regular expression ({e})"))
        return out


def _key_for(default: str, what: str):
    return key(default, f"key for {what}")


@dataclass
class KeysConfig:
    """The live screen's keys, as Textual names them: 1, u, space, question_mark, ctrl+x."""

    mode_lg: str = _key_for("1", "the true mode LG (level ground)")
    mode_us: str = _key_for("2", "the true mode US (stairs up)")
    mode_ds: str = _key_for("3", "the true mode DS (stairs down)")
    mode_ur: str = _key_for("4", "the true mode UR (ramp up)")
    mode_dr: str = _key_for("5", "the true mode DR (ramp down)")
    undo: str = _key_for("u", "undoing the last label change")
    marker: str = _key_for("m", "a marker with an optional note")
    record: str = _key_for("r", "starting / stopping a trial")
    freeze: str = _key_for("space", "freezing the display")
    help: str = _key_for("question_mark", "the help screen")
    quit: str = _key_for("q", "quitting (ctrl+q always quits too)")


@dataclass
class LslConfig:
    """Lab Streaming Layer: walkcap's streams out, other devices' streams into the recording."""

    enabled: bool = key(False, "LSL outlets: walkcap IMU, walkcap Terrain, walkcap Markers")
    record: list[str] = key(
        doc='names of other devices\' LSL streams recorded into each trial, e.g. ["EMG"]',
        factory=list,
    )
    remote_control: bool = key(False, "LabRecorder's start / stop / filename commands on 127.0.0.1")
    remote_port: int = key(22345, "the remote control's TCP port (LabRecorder's)")
    remote_any_root: bool = key(
        False, "let a remote {root:DIR} name any folder, not only one in recordings"
    )
    remote_token: str = key(
        "",
        "if set, a remote-control connection starts with the line `token <it>`",
        secret=True,
    )


@dataclass
class FoxgloveConfig:
    """A live Foxglove WebSocket server with the recording's topics and schemas."""

    enabled: bool = key(False, "serve the live session's topics to Foxglove over a WebSocket")
    host: str = key(
        "127.0.0.1", "address the Foxglove server listens on (localhost only unless changed)"
    )
    port: int = key(8765, "the Foxglove server's port (Foxglove's default)")
    # encoding them shares the pipeline's interpreter: a few a second keep the live view
    # off the pipeline's latency (`walkcap bench`)
    image_hz: float = key(5.0, "depth, images and clouds sent at most this often, per second")


_TEXT = ("drop", "replace", "keep")


@dataclass
class ShareConfig:
    """What copies made for sharing keep of the personal fields (`walkcap share`, and the
    BIDS export): the list is in docs/recordings.md#personal-data."""

    notes: str = key(
        "drop", "the form's Notes: drop, replace (by `replacement`) or keep", choices=_TEXT
    )
    operator: str = key(
        "drop", "the operator: drop, replace (by `replacement`) or keep", choices=_TEXT
    )
    markers: str = key(
        "replace",
        "a marker's typed note: replace (the text 'marker'), drop (empty) or keep; its time stays",
        choices=_TEXT,
    )
    replacement: str = key("[removed]", "what `replace` puts in the notes and the operator")
    body: str = key(
        "keep",
        "age, height, weight, residual limb: keep, coarsen (age in 5-year bands, 90 and over "
        "as 90; height to 0.05 m; weight to 5 kg; limb to 5 cm) or drop",
        choices=("keep", "coarsen", "drop"),
    )
    sex: str = key("keep", "the subject's sex: keep or drop", choices=("keep", "drop"))
    amputation: str = key("keep", "amputee and side: keep or drop", choices=("keep", "drop"))
    dates: str = key(
        "subject",
        "dates moved back by whole days: one offset per subject, one for the study, or keep "
        "(the real dates)",
        choices=("subject", "study", "keep"),
    )
    secret: str = key(
        "",
        "the study's secret the date offsets derive from (the same secret, the same offsets "
        "in every run); kept with the study's key list, never in what is shared",
        secret=True,
    )
    max_shift_days: int = key(3650, "derived offsets move dates back by 1 to this many days")

    def problems(self) -> list[tuple[str, str]]:
        out = choice_problems(self)
        if self.max_shift_days < 1:
            out.append(("max_shift_days", "at least 1"))
        return out


@dataclass
class StudyConfig:
    """The study a BIDS dataset describes (`walkcap export --format bids`)."""

    name: str = key("", "the dataset's name (dataset_description.json Name)")
    authors: list[str] = key(
        doc='the dataset\'s authors, one name a string, e.g. ["A. Author", "B. Author"]',
        factory=list,
    )
    license: str = key("", "the data's license, an SPDX name, e.g. CC0-1.0 or CC-BY-4.0")
    institution_name: str = key("", "the institution that recorded the data")
    institution_address: str = key("", "the institution's address")
    institution_department: str = key("", "the department that recorded the data")
    instructions: str = key("", "what the participants were told to do, as they were told")
    imu_placement: str = key(
        "thigh", "where the IMU sits on the body (BIDS motion `placement`), e.g. left thigh"
    )

    def problems(self) -> list[tuple[str, str]]:
        out = []
        if not self.imu_placement.strip():
            out.append(("imu_placement", "a body part, e.g. thigh"))
        if any(not a.strip() for a in self.authors):
            out.append(("authors", "names, none empty"))
        return out


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
    share: ShareConfig = field(default_factory=ShareConfig)
    study: StudyConfig = field(default_factory=StudyConfig)
    source: str = ""  # the file it was read from, empty for defaults


def sections() -> list[tuple[str, type]]:
    """Every section of the file, (name, dataclass), in the file's order."""
    hints = typing.get_type_hints(Config)
    return [(f.name, hints[f.name]) for f in dataclasses.fields(Config) if f.name != "source"]


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
    for name, value in table.items():
        full = f"{prefix}.{name}" if prefix else name
        if name not in names or name == "source":
            known = ", ".join(sorted(n for n in names if n != "source"))
            raise ConfigError(f"unknown key {full!r} (known here: {known})")
        try:
            kwargs[name] = _convert(value, hints[name], full)
        except ConfigError:
            field = next(f for f in dataclasses.fields(cls) if f.name == name)
            if field.metadata.get("secret"):  # its value is said nowhere, not even here
                raise ConfigError(f"{full}: expected {_type_name(hints[name])}") from None
            raise
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


def secrets_of(config: Config) -> list[str]:
    """The values of the secret keys that are set (a token): what nothing may print."""
    out = []
    for name, cls in sections():
        section = getattr(config, name)
        for f in dataclasses.fields(cls):
            value = getattr(section, f.name)
            if f.metadata.get("secret") and isinstance(value, str) and value:
                out.append(value)
    return out


def dumps(config: Config, secrets: bool = True) -> str:
    """The configuration as TOML (every key, so a saved file documents itself). Without
    `secrets` (the copy a recording carries), a secret key that is set reads as empty, with
    a comment saying it was set."""
    lines = []
    fields = {name: {f.name: f for f in dataclasses.fields(cls)} for name, cls in sections()}
    for section, table in to_dict(config).items():
        lines.append(f"[{section}]")
        for k, v in table.items():
            f = fields.get(section, {}).get(k)
            if not secrets and v and f is not None and f.metadata.get("secret"):
                lines.append(f'{k} = ""  # set, not kept in recordings')
            else:
                lines.append(f"{k} = {_toml_value(v)}")
        lines.append("")
    return "\n".join(lines)


def documented(config: Config) -> str:
    """The configuration as TOML with a comment per key: what it is and its default.

    What `walkcap config` prints; it loads back as the same configuration, but for a
    secret key that is set (a token): that reads as empty, with a comment saying it is set.
    """
    defaults = to_dict(Config())
    lines = [
        "# walkcap configuration: every key with what it does and its default.",
        "# Save as walkcap.toml (or pass --config FILE); keys left out take their default.",
        "# [keys] take Textual key names: 1, u, space, question_mark, ctrl+x, ...",
        "",
    ]
    for name, cls in sections():
        values = dataclasses.asdict(getattr(config, name))
        lines.append(f"[{name}]")
        for f in dataclasses.fields(cls):
            value = values[f.name]
            default = _toml_value(defaults[name][f.name])
            if len(default) > 40:  # a matrix: `walkcap config --default` shows it in full
                default = "printed by --default"
            lines.append(f"# {_described(f)} [default: {default}]")
            if value and f.metadata.get("secret"):  # set: loads back empty, says so
                lines.append(f'{f.name} = ""  # set, not shown (see your configuration file)')
            elif value and isinstance(value, list) and isinstance(value[0], list):
                rows = [f"    {_toml_value(row)}," for row in value]
                lines += [f"{f.name} = [", *rows, "]"]
            else:
                lines.append(f"{f.name} = {_toml_value(value)}")
        lines.append("")
    return "\n".join(lines)


def _described(f: dataclasses.Field) -> str:
    """A key's doc, and the names it takes when they come from a registry or a set."""
    choices = choices_of(f)
    doc = doc_of(f) or f.name
    return doc if choices is None else f"{doc} (one of: {' | '.join(choices)})"


REFERENCE_COMMAND = "walkcap config --markdown > docs/configuration.md"


def reference() -> str:
    """docs/configuration.md: every section and key with its default, what it does and,
    for a name out of a registry, the names registered. Made from the sections' fields;
    `walkcap config --markdown` prints it."""
    defaults = to_dict(Config())
    lines = [
        "# Configuration reference",
        "",
        f"<!-- generated by `{REFERENCE_COMMAND}`; edit the dataclass fields, not this file -->",
        "",
        "walkcap reads one TOML file: `--config PATH`, else `$WALKCAP_CONFIG`, else "
        "`./walkcap.toml` when it exists, else the defaults below. Keys left out take their "
        "default; an unknown key, a value of the wrong type or out of its range stops walkcap "
        "with one line naming the key, before any device opens. Command-line flags override "
        "the file.",
        "",
        "`walkcap config` prints the effective configuration as TOML with these comments; "
        "`walkcap config --default` prints the defaults.",
        "",
    ]
    for name, cls in sections():
        about = " ".join((cls.__doc__ or "").split())
        lines += [
            f"## [{name}]",
            "",
            about,
            "",
            "| key | default | what it does |",
            "|---|---|---|",
        ]
        matrices = []
        for f in dataclasses.fields(cls):
            value = defaults[name][f.name]
            what = _described(f).replace("|", "\\|")
            if value and isinstance(value, list) and isinstance(value[0], list):
                matrices.append((f.name, value))
                shown = "below"
            else:
                shown = f"`{_toml_value(value)}`"
            lines.append(f"| `{f.name}` | {shown} | {what} |")
        for key_name, rows in matrices:
            lines += ["", f"Default `{key_name}`:", "", "```toml", f"{key_name} = ["]
            lines += [f"    {_toml_value(row)}," for row in rows]
            lines += ["]", "```"]
        lines.append("")
    return "\n".join(lines)


def save(config: Config, path: str | os.PathLike) -> Path:
    """Write the whole configuration atomically (a crash never leaves half a file)."""
    path = check_replaceable(path)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(dumps(config))
    os.replace(tmp, path)
    return path
