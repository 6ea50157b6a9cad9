"""`walkcap config`: the effective configuration as TOML, every key commented."""

from __future__ import annotations

import os
import re
from pathlib import Path

HELP = (
    "print the effective configuration as TOML (every key, its default, what it does); "
    "--set writes a key into the configuration file"
)


def add_arguments(parser) -> None:
    parser.add_argument(
        "--default",
        action="store_true",
        help="print the defaults, ignoring any configuration file",
    )
    parser.add_argument(
        "--markdown",
        action="store_true",
        help="print the configuration reference (docs/configuration.md) in Markdown",
    )
    parser.add_argument(
        "--set",
        action="append",
        metavar="SECTION.KEY=VALUE",
        help="write one key into the configuration file (the one in use, else ./walkcap.toml; "
        "the rest of it kept as it is), e.g. --set session.recordings=/mnt/data/walkcap; "
        "repeatable",
    )


def run(args, config) -> int:
    from capture import config as config_mod

    if args.set:
        return set_keys(args.set, config)
    if args.markdown:
        print(config_mod.reference(), end="")
        return 0
    if args.default:
        config = config_mod.Config()
    elif config.source:
        print(f"# read from {config.source}")
    print(config_mod.documented(config), end="")
    return 0


def set_keys(assignments: list[str], config) -> int:
    """Each `section.key=value` checked as the loader checks it, then written into the
    file: the key's line replaced, or added to its table, or the table added."""
    from capture import config as config_mod
    from capture.errors import ConfigError

    path = Path(config.source) if config.source else config_mod.DEFAULT_PATH
    try:
        text = path.read_text(encoding="utf-8") if path.exists() else ""
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"cannot read {path}: {e}") from None
    for assignment in assignments:
        dotted, eq, value = assignment.partition("=")
        dotted = dotted.strip()
        section, _, key = dotted.partition(".")
        if not eq or not key or not hasattr(config, section):
            raise ConfigError(f"--set {assignment!r}: expected SECTION.KEY=VALUE")
        config_mod.override(config, dotted, _value(config, section, key, value), f"--set {dotted}")
        typed = getattr(getattr(config, section), key)
        text = _with_key(text, section, key, _toml(typed))
    config_mod.from_dict(_parsed(text, path))  # the whole file loads before it is written
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)
    except OSError as e:
        raise ConfigError(f"cannot write {path}: {e.strerror}") from None
    for assignment in assignments:
        print(f"set {assignment.strip()} in {path}")
    return 0


def _value(config, section: str, key: str, text: str):
    """VALUE as the key takes it: text for a text key, else a TOML value (15, true, [1, 2]),
    else the text (the type check then names what was expected)."""
    import tomllib
    import typing

    hint = typing.get_type_hints(type(getattr(config, section))).get(key)
    if hint is str:
        return text
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def _parsed(text: str, path: Path) -> dict:
    import tomllib

    from capture.errors import ConfigError

    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: not valid TOML after --set: {e}") from None


def _toml(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return '"' + str(value).replace("\\", "\\\\").replace('"', '\\"') + '"'


_TABLE = re.compile(r"^\s*\[([^\[\]]+)\]\s*(#.*)?$")


def _with_key(text: str, section: str, key: str, value: str) -> str:
    """`text` with `key = value` in table `section`, everything else as it was."""
    lines = text.splitlines()
    start = next(
        (
            i
            for i, line in enumerate(lines)
            if (m := _TABLE.match(line)) and m[1].strip() == section
        ),
        None,
    )
    if start is None:
        tail = (
            ["", f"[{section}]", f"{key} = {value}"]
            if lines
            else [f"[{section}]", f"{key} = {value}"]
        )
        return "\n".join(lines + tail) + "\n"
    end = next((i for i in range(start + 1, len(lines)) if _TABLE.match(lines[i])), len(lines))
    own = re.compile(rf"^\s*{re.escape(key)}\s*=")
    for i in range(start + 1, end):
        if own.match(lines[i]):
            lines[i] = f"{key} = {value}"
            break
    else:
        lines.insert(start + 1, f"{key} = {value}")
    return "\n".join(lines) + "\n"
