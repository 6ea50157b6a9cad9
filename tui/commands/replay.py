"""`walkcap replay`: run the pipeline again on a recording into a new recording"""
from tui.cli import NotYetAvailable

HELP = "run the pipeline again on a recording into a new recording"


def add_arguments(parser) -> None:
    parser.add_argument("rest", nargs="*", help="(not available yet)")


def run(args, config) -> int:
    raise NotYetAvailable("not available yet: it lands with the [recording] issue")
