"""`walkcap replay`: the pipeline again on a recording (e.g. with another model), into a
new recording; or `--tui` to view it in the session screens and correct labels."""

from __future__ import annotations

import sys

from tui.commands import finish_recording

HELP = "run the pipeline again on a recording into a new recording (or view it with --tui)"


def add_arguments(parser) -> None:
    parser.add_argument("file", metavar="FILE", help="a walkcap recording (.mcap)")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--speed", type=float, metavar="X", help="X times the recorded pace")
    pace.add_argument("--fast", action="store_true", help="as fast as possible (default)")
    parser.add_argument("--model", metavar="PATH", help="classifier weights (default: bundled)")
    parser.add_argument(
        "-o",
        "--out",
        metavar="FILE",
        help="output file (default: FILE.replay.mcap beside the original)",
    )
    # viewing with play/pause/seek and label corrections into a new file
    parser.add_argument(
        "--tui",
        action="store_true",
        help="show the recording in the terminal UI: p play/pause, "
        "left/right seek, 1-5 correct labels, w save them to a new file",
    )


def run(args, config) -> int:
    from capture.config import override
    from capture.errors import CaptureError

    if args.tui:
        from tui.replay import run_tui

        return run_tui(args.file, config)
    if args.speed is not None and args.speed <= 0:
        raise CaptureError("--speed must be positive")
    if args.model:
        override(config, "model.path", args.model)
    from tqdm import tqdm

    from capture.replay import replay

    bar = tqdm(unit="frame", desc="replay", file=sys.stderr, disable=not sys.stderr.isatty())
    try:
        report = replay(
            args.file, config, output=args.out, speed=args.speed, progress=lambda n: bar.update(1)
        )
    finally:
        bar.close()
    stats = report.stats
    print(
        f"{report.frames} frames, {report.seconds_recorded:.1f} s recorded in "
        f"{report.seconds_taken:.1f} s ({report.speedup:.1f}x real time)",
        file=sys.stderr,
    )
    return finish_recording("replay", stats, report.output)
