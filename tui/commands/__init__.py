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
