"""One module per `walkcap` subcommand: HELP, add_arguments(parser), run(args, config)."""

import argparse


def count(minimum: int, maximum: int | None = None):
    """An argparse type: an integer of at least `minimum` (and at most `maximum`), else a
    one-line usage error."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < minimum or (maximum is not None and value > maximum):
            valid = f">= {minimum}" if maximum is None else f"within {minimum}..{maximum}"
            raise argparse.ArgumentTypeError(f"must be {valid}, got {value}")
        return value

    return parse


def seconds(text: str) -> float:
    """An argparse type: a positive, finite number of seconds."""
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text}")
    return value


def finish_recording(command: str, stats, path) -> int:
    """Print the file path last (scripts take it); a failed recording is one error line."""
    if stats.state == "failed":
        from tui.cli import error_line

        error_line(command, stats.message)
        print(path)
        return 1
    print(path)
    return 0
