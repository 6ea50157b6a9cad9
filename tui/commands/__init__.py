"""One module per `walkcap` subcommand: HELP, add_arguments(parser), run(args, config)."""

import argparse


def count(minimum: int):
    """An argparse type: an integer of at least `minimum`, else a one-line usage error."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {value}")
        return value

    return parse


def finish_recording(command: str, stats, path) -> int:
    """Print the file path last (scripts take it); a failed recording is one error line."""
    import sys

    from capture.recorder import RecorderState

    if stats.state == RecorderState.FAILED:
        print(f"walkcap {command}: error: {stats.message}", file=sys.stderr)
        print(path)
        return 1
    print(path)
    return 0
