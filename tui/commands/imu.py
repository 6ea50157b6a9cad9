"""`walkcap imu`: IMU tools: list ports, device info, stream, emulate, decode captures"""
from tui.cli import NotYetAvailable

HELP = "IMU tools: list ports, device info, stream, emulate, decode captures"


def add_arguments(parser) -> None:
    parser.add_argument("rest", nargs="*", help="(not available yet)")


def run(args, config) -> int:
    raise NotYetAvailable("not available yet: it lands with the [imu] issue")
