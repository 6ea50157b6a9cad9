"""`walkcap bench`: measure speed, latency and size on mock devices"""
from tui.cli import NotYetAvailable

HELP = "measure speed, latency and size on mock devices"


def add_arguments(parser) -> None:
    parser.add_argument("rest", nargs="*", help="(not available yet)")


def run(args, config) -> int:
    raise NotYetAvailable("not available yet: it lands with the [bench] issue")
