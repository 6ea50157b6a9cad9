"""`walkcap record`: record a session headless into an MCAP file"""
from tui.cli import NotYetAvailable

HELP = "record a session headless into an MCAP file"


def add_arguments(parser) -> None:
    parser.add_argument("rest", nargs="*", help="(not available yet)")


def run(args, config) -> int:
    raise NotYetAvailable("not available yet: it lands with the [recording] issue")
