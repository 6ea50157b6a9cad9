"""`walkcap synth`: write simulated sessions (training sets and recordings)"""
from tui.cli import NotYetAvailable

HELP = "write simulated sessions (training sets and recordings)"


def add_arguments(parser) -> None:
    parser.add_argument("rest", nargs="*", help="(not available yet)")


def run(args, config) -> int:
    raise NotYetAvailable("not available yet: it lands with the [camera] issue")
