"""`walkcap replay`: the pipeline again on recordings (e.g. with another model), each into
a new recording; or `--tui` to view one in the session screens and correct labels."""

from __future__ import annotations

import sys

from tui.commands import add_cluster_argument, finish_recording, positive

HELP = "run the pipeline again on recordings into new recordings (or view one with --tui)"


def add_arguments(parser) -> None:
    parser.add_argument(
        "files", nargs="+", metavar="FILE", help="walkcap recordings (.mcap), one or more"
    )
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument(
        "--speed",
        type=positive("times the recorded pace"),
        metavar="X",
        help="X times the recorded pace",
    )
    pace.add_argument("--fast", action="store_true", help="as fast as possible (default)")
    parser.add_argument("--model", metavar="PATH", help="classifier weights (default: bundled)")
    parser.add_argument(
        "-o",
        "--out",
        metavar="FILE|DIR",
        help="output file (default: FILE.replay.mcap beside the original); with several "
        "FILEs, the folder for their replays",
    )
    add_cluster_argument(parser, "each recording's replay")
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

    several = len(args.files) > 1
    for f in args.files:
        _check_subject(f, config.session.subject_pattern)
    if args.tui:
        if several:
            raise CaptureError("--tui shows one recording: give one FILE")
        from tui.replay import run_tui

        return run_tui(args.files[0], config)
    if args.cluster and args.speed is not None:
        raise CaptureError("--cluster replays as fast as possible: leave out --speed")
    if args.model:
        override(config, "model.path", args.model)
    outputs = _outputs(args.files, args.out)
    if args.cluster:
        return _on_cluster(args, config, outputs)
    status = 0
    for source, output in zip(args.files, outputs):
        status = max(status, _replay_one(args, config, source, output))
    return status


def _check_subject(path: str, pattern: str) -> None:
    """A replay carries its source's subject id into a new file: the id fits the study's
    pattern, or the replay is refused before anything runs (an unreadable file is left to the
    replay to report)."""
    from capture.errors import CaptureError
    from capture.live.trials import check_pseudonym
    from capture.recording import open_recording

    try:
        subject = open_recording(path).trial[0]
    except (CaptureError, OSError):
        return
    if subject:
        try:
            check_pseudonym(str(subject), pattern)
        except CaptureError as e:
            raise CaptureError(f"{path}: {e}") from None


def _outputs(files: list[str], out: str | None) -> list[str | None]:
    """Each FILE's output: --out for one FILE; for several, their default names, in the
    --out folder when given (None: decided by replay, beside the original)."""
    from pathlib import Path

    from capture.corpus.replay import default_output
    from capture.errors import CaptureError

    if len(files) == 1:
        return [out]
    names = [Path(f).name for f in files]
    if out is not None and len(set(names)) != len(names):
        raise CaptureError("two FILEs have the same name: their replays would meet in --out")
    if out is not None and Path(out).suffix.lower() == ".mcap":
        raise CaptureError(f"--out {out}: with several FILEs, --out names a folder")
    folder = Path(out) if out is not None else None
    if folder is not None:
        folder.mkdir(parents=True, exist_ok=True)
    outputs = []
    for f in files:
        o = default_output(Path(f), folder)
        while str(o) in outputs:  # one FILE given twice: its replays one after the other
            o = o.with_name(o.stem + "+.mcap")
        outputs.append(str(o))
    return outputs


def _replay_one(args, config, source: str, output: str | None) -> int:
    from tqdm import tqdm

    from capture.corpus.replay import replay

    bar = tqdm(unit="frame", desc="replay", file=sys.stderr, disable=not sys.stderr.isatty())
    try:
        report = replay(
            source, config, output=output, speed=args.speed, progress=lambda n: bar.update(1)
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


def _on_cluster(args, config, outputs: list[str | None]) -> int:
    """One task per recording; the new files' paths printed in the order given."""
    from pathlib import Path

    from capture.corpus import jobs
    from capture.corpus.cluster import ClusterError
    from capture.corpus.replay import default_output, replay_file

    where = jobs.Cluster(args.cluster)
    outputs = [o or str(default_output(Path(f))) for f, o in zip(args.files, outputs)]
    tasks = [
        jobs.Task(
            Path(f).name,
            replay_file,
            (jobs.task_path(where, f), config, jobs.task_path(where, o)),
        )
        for f, o in zip(args.files, outputs)
    ]
    try:
        reports = jobs.run(tasks, where, desc="replay", unit="recording")
    except ClusterError as e:  # the replays written are still said
        for o, report in zip(outputs, e.results):
            if report is not None:
                print(o)
        raise
    frames = sum(r.frames for r in reports)
    recorded = sum(r.seconds_recorded for r in reports)
    print(
        f"{len(reports)} recording(s), {frames} frames, {recorded:.1f} s recorded",
        file=sys.stderr,
    )
    for o in outputs:
        print(o)
    return 0
