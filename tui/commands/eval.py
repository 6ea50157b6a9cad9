"""`walkcap eval`: evaluate classifiers and fusion on score files or recordings"""
from tui.cli import NotYetAvailable

HELP = "evaluate classifiers and fusion on score files or recordings"


def add_arguments(parser) -> None:
    parser.add_argument("rest", nargs="*", help="(not available yet)")


def run(args, config) -> int:
    raise NotYetAvailable("not available yet: it lands with the [fusion] issue")
