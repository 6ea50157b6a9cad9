"""The `walkcap` command: subcommands, configuration, and one clear line per user error.

Each subcommand is a module in `tui/commands/` with `HELP`, `add_arguments(parser)` and
`run(args, config) -> int`. Modules import heavy libraries (torch, open3d) inside `run`,
so `walkcap --help` stays instant.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
import traceback

import capture
from tui.logfile import REDACTOR

COMMANDS = (
    "tui",
    "record",
    "replay",
    "info",
    "export",
    "share",
    "forget",
    "recover",
    "eval",
    "train",
    "synth",
    "calibrate",
    "bench",
    "imu",
    "check",
    "config",
)


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line naming the command and the fix."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def _user_errors() -> tuple[type[BaseException], ...]:
    from devices.errors import WalkcapError

    return (WalkcapError, OSError)


class _Version(argparse.Action):
    """--version: the installed distribution's version, looked up only when asked for."""

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"walkcap {capture.__version__}")
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="walkcap",
        description="Data-collection sessions for assistive walking: depth camera + IMU, "
        "live terrain classification with HMM fusion, synchronized MCAP recordings.",
    )
    parser.add_argument("--version", action=_Version, nargs=0, help="show the version and exit")
    _add_common(parser, argparse.SUPPRESS)
    parser.set_defaults(config=None, verbose=0, _parser=parser)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in COMMANDS:
        module = importlib.import_module(f"tui.commands.{name}")
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        # before or after the subcommand alike: `walkcap --config X tui` = `walkcap tui --config X`
        _add_common(p, argparse.SUPPRESS)
        module.add_arguments(p)
        p.set_defaults(_module=module)
        _mark_parsers(p)
    return parser


def _mark_parsers(parser: argparse.ArgumentParser) -> None:
    """Each (sub)command's parser in its parsed arguments: a flag it does not know is
    reported by it, with its own `--help`."""
    parser.set_defaults(_parser=parser)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                _mark_parsers(sub)


def _add_common(parser: argparse.ArgumentParser, default) -> None:
    parser.add_argument(
        "--config",
        metavar="PATH",
        default=default,
        help="configuration file (TOML); default: $WALKCAP_CONFIG or ./walkcap.toml when present",
    )
    parser.add_argument("-v", "--verbose", action="count", default=default, help="more log output")


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if args.command is None:  # plain `walkcap` opens the terminal UI
        args, extra = parser.parse_known_args(
            ["tui", *(argv if argv is not None else sys.argv[1:])]
        )
    if extra:
        args._parser.error(f"unrecognized arguments: {' '.join(extra)}")
    _log_to_stderr(args.command, args.verbose)
    try:
        from capture import config as config_mod

        config = config_mod.load(args.config)
        REDACTOR.secrets = config_mod.secrets_of(config)  # out of every line said
        return int(args._module.run(args, config) or 0)
    except KeyboardInterrupt:
        print("walkcap: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `walkcap info FILE | head`: the reader left, nothing is wrong
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except Exception as e:
        if isinstance(e, _user_errors()):
            error_line(args.command, _describe(e))
            return 1
        if os.environ.get("WALKCAP_DEBUG"):
            raise
        log = _write_crash_log()
        what = REDACTOR.redact(f"{type(e).__name__}: {e}")
        print(
            f"walkcap {args.command}: internal error: {what} (details in {log}; please report it)",
            file=sys.stderr,
        )
        return 70


class _StderrLog(logging.Handler):
    """Log records on stderr. By default one line each, named like the command's errors
    (`walkcap record: error: ...`), without timestamps or tracebacks; with -v the logger's
    name and time, and tracebacks. It remembers what it said, so that the command's last
    error line is not said twice."""

    def __init__(self, command: str, verbose: int) -> None:
        super().__init__(logging.WARNING - 10 * min(verbose, 2))
        self.addFilter(REDACTOR)
        self.command = command
        self.verbose = verbose
        self.said: list[str] = []
        if verbose:
            self.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))

    def emit(self, record: logging.LogRecord) -> None:
        try:
            message = record.getMessage()
            if self.verbose:
                line = self.format(record)
            else:
                text = " ".join(message.split())  # one line, whatever the message holds
                line = f"walkcap {self.command}: {record.levelname.lower()}: {text}"
            self.said.append(message)
            del self.said[:-50]
            print(line, file=sys.stderr, flush=True)
        except Exception:
            self.handleError(record)


_handler: _StderrLog | None = None


def _log_to_stderr(command: str | None, verbose: int) -> None:
    global _handler
    root = logging.getLogger()
    if _handler is not None:
        root.removeHandler(_handler)
    _handler = _StderrLog(command or "walkcap", verbose)
    root.addHandler(_handler)
    if root.level > _handler.level:  # -v lowers it; never raised over what is set
        root.setLevel(_handler.level)


def error_line(command: str, text: str) -> None:
    """The command's error, once: not again when a log line just said the same."""
    text = REDACTOR.redact(text)
    if _handler is not None and any(text in said for said in _handler.said):
        return
    print(f"walkcap {command}: error: {text}", file=sys.stderr)


def _describe(e: BaseException) -> str:
    if isinstance(e, OSError) and e.strerror:
        where = f": {e.filename}" if e.filename else ""
        return f"{e.strerror}{where}"
    return str(e)


def _write_crash_log() -> str:
    path = os.path.join(os.path.expanduser("~"), ".cache", "walkcap", "crash.log")
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600), "a") as f:
            f.write(REDACTOR.redact(traceback.format_exc()) + "\n")
    except OSError:
        return "(no crash log could be written)"
    return path


if __name__ == "__main__":
    sys.exit(main())
