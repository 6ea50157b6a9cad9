"""`walkcap info`: describe a recording: topics, counts, rates, gaps, metadata"""
from tui.cli import NotYetAvailable

HELP = "describe a recording: topics, counts, rates, gaps, metadata"


def add_arguments(parser) -> None:
    parser.add_argument("rest", nargs="*", help="(not available yet)")


def run(args, config) -> int:
    raise NotYetAvailable("not available yet: it lands with the [recording] issue")
