"""`walkcap config`: the effective configuration as TOML, every key commented."""

from __future__ import annotations

HELP = "print the effective configuration as TOML (every key, its default, what it does)"


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


def run(args, config) -> int:
    from capture import config as config_mod

    if args.markdown:
        print(config_mod.reference(), end="")
        return 0
    if args.default:
        config = config_mod.Config()
    elif config.source:
        print(f"# read from {config.source}")
    print(config_mod.documented(config), end="")
    return 0
