"""`walkcap calibrate`: estimate the camera mounting from standing on level ground"""
from tui.cli import NotYetAvailable

HELP = "estimate the camera mounting from standing on level ground"


def add_arguments(parser) -> None:
    parser.add_argument("rest", nargs="*", help="(not available yet)")


def run(args, config) -> int:
    raise NotYetAvailable("not available yet: it lands with the [preprocess] issue")
