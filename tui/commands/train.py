"""`walkcap train`: train the terrain classifier"""
from tui.cli import NotYetAvailable

HELP = "train the terrain classifier"


def add_arguments(parser) -> None:
    parser.add_argument("rest", nargs="*", help="(not available yet)")


def run(args, config) -> int:
    raise NotYetAvailable("not available yet: it lands with the [cnn] issue")
