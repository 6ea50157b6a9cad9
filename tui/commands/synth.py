"""`walkcap synth`: write simulated sessions (training sets and recordings)

    walkcap synth --out DIR [--sessions N] [--preset indoor|outdoor|both] [--seed S]
                  [--format dataset] [--frames N] [--workers N] [--cluster ADDRESS|local]

`--format recording` writes each session as a walkcap recording (MCAP, every topic of a
live mock session, labels from the simulator's truth), for eval, train and replay.
`--format dataset` renders each session with the terrain-walk simulator at the camera's
rate, levels every frame with a noisy IMU orientation, preprocesses it as the live
pipeline does and writes one compressed .npz per session (images, true modes, flags,
metadata) for `walkcap train`. Session i uses seed S + i; "both" alternates presets.
"""

from __future__ import annotations

from tui.commands import add_cluster_argument, add_preset_argument, count, positive, seed_max

HELP = "write simulated sessions (training sets and recordings)"
_positive = count(1)


def add_arguments(parser) -> None:
    parser.add_argument("-o", "--out", metavar="DIR", required=True, help="output folder")
    parser.add_argument(
        "--sessions", type=_positive, default=1, metavar="N", help="number of sessions (default 1)"
    )
    add_preset_argument(parser)
    parser.add_argument(
        "--seed",
        type=count(0, lambda: seed_max() - 100_000),
        default=0,
        metavar="S",
        help="seed S: synthesized session i uses seed S + i (default 0)",
    )
    parser.add_argument(
        "--format",
        choices=("dataset", "recording"),
        default="dataset",
        help="dataset: .npz training sessions (default); recording: MCAP",
    )
    parser.add_argument(
        "--frames",
        type=_positive,
        metavar="N",
        help="at most N frames per session (default: the whole walk)",
    )
    parser.add_argument(
        "--workers",
        type=_positive,
        default=1,
        metavar="N",
        help="processes synthesizing sessions in parallel (default 1)",
    )
    add_cluster_argument(parser, "each session")
    parser.add_argument(
        "--imu-error-deg",
        type=positive("degrees", zero=True),
        default=None,
        metavar="DEG",
        help="IMU roll/pitch error, RMS, drifting slowly (default 1.0: the MTi 1-series)",
    )
    parser.add_argument(
        "--fixed-walker",
        action="store_true",
        help="use the [simulator] walker for every session instead of "
        "drawing speed, cadence, camera height and tilt per session",
    )


def run(args, config) -> int:
    if args.format == "recording":
        return _recordings(args, config)
    from dataclasses import replace

    from capture.corpus.dataset import SynthSettings, synth_dataset

    settings = SynthSettings(max_frames=args.frames or 0, vary_walker=not args.fixed_walker)
    if args.imu_error_deg is not None:
        error = replace(settings.imu_error, roll_pitch_deg=args.imu_error_deg)
        settings = replace(settings, imu_error=error)
    paths = synth_dataset(
        args.out,
        args.sessions,
        args.preset,
        args.seed,
        params=config.preprocess,
        mounting=config.mounting,
        settings=settings,
        simulator_config=config.simulator,
        workers=args.workers,
        cluster=args.cluster,
    )
    print(f"wrote {len(paths)} session(s) to {args.out}")
    return 0


def _recordings(args, config) -> int:
    """One MCAP per session, as a live mock session would record it, with simulator labels:
    here, in `--workers` processes or on the cluster; each path printed once written."""
    import sys
    from pathlib import Path

    from capture.corpus import jobs
    from capture.corpus.dataset import session_plan
    from capture.corpus.synth import synth_recording_file

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    plan = session_plan(args.sessions, args.preset, args.seed)
    paths = [
        out / f"SIM_{preset}_t{i + 1:02d}_seed{seed}.mcap" for i, (preset, seed) in enumerate(plan)
    ]
    where = jobs.choose(args.cluster, args.workers)
    tasks = [
        jobs.Task(
            path.name,
            synth_recording_file,
            (
                jobs.task_path(where, path),
                config,
                preset,
                seed,
                i + 1,
                args.frames or 0,
                not args.fixed_walker,
            ),
        )
        for i, (path, (preset, seed)) in enumerate(zip(paths, plan))
    ]
    jobs.run(tasks, where, desc="synth", unit="recording", on_result=lambda i, _: print(paths[i]))
    print(f"wrote {len(paths)} recording(s) to {out}", file=sys.stderr)
    return 0
