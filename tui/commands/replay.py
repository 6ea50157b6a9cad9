"""`walkcap replay`: run the pipeline again on a recording into a new recording"""
from tui.cli import NotYetAvailable

HELP = "run the pipeline again on a recording into a new recording"


def add_arguments(parser) -> None:
    parser.add_argument("rest", nargs="*", help="(not available yet)")
    # [tui] issue: viewing with play/pause/seek and label corrections into a new file
    parser.add_argument("--tui", action="store_true",
                        help="show the recording (first argument) in the terminal UI: p play/pause, "
                        "left/right seek, 1-5 correct labels, w save them to a new file")


def run(args, config) -> int:
    if args.tui and args.rest:
        from tui.replay import run_tui

        return run_tui(args.rest[0], config)
    raise NotYetAvailable("not available yet: it lands with the [recording] issue")
