"""`walkcap train`: its flags and the TrainSettings fields they set."""

import argparse

from inference.training.settings import TrainSettings
from tui.commands import train


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser()
    train.add_arguments(parser)
    return parser


def test_each_setting_flag_defaults_to_its_field_and_shows_the_default():
    parser = _parser()
    args = parser.parse_args(["--data", "x"])
    d = TrainSettings()
    for flag, *_ in train._SETTINGS:
        name = flag[2:].replace("-", "_")
        assert getattr(args, name) == getattr(d, name), flag
    text = " ".join(parser.format_help().split())
    assert "at most N epochs (default 12)" in text
    assert "learning rate (default 0.001)" in text


def test_a_flag_reaches_its_setting():
    args = _parser().parse_args(["--data", "x", "--batch-size", "8", "--val-fraction", "0.3"])
    assert args.batch_size == 8 and args.val_fraction == 0.3
