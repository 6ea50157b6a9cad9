"""`walkcap recover`: rebuild a valid MCAP from a recording cut off by a crash"""
from tui.cli import NotYetAvailable

HELP = "rebuild a valid MCAP from a recording cut off by a crash"


def add_arguments(parser) -> None:
    parser.add_argument("rest", nargs="*", help="(not available yet)")


def run(args, config) -> int:
    raise NotYetAvailable("not available yet: it lands with the [recording] issue")
