"""`walkcap bench`: speed, latency and size on mock devices, each figure against its goal."""

from __future__ import annotations

import json
import sys

from tui.commands import bench_corpus, positive, seconds

HELP = "measure speed, latency and size on mock devices"


def add_arguments(parser) -> None:
    parser.add_argument("--json", action="store_true", help="machine-readable results")
    parser.add_argument(
        "--seconds", type=seconds, default=15.0, help="length of each mock session run (default 15)"
    )
    parser.add_argument(
        "--soak",
        type=positive("minutes"),
        metavar="MINUTES",
        help="instead: a full mock session at 45 fps for MINUTES; "
        "memory and latency over time, drops",
    )
    parser.add_argument(
        "--cluster",
        metavar="ADDRESS|local",
        help="instead: synth and replay of --sessions sessions with --cluster against one "
        "process, --rounds interleaved rounds; the cluster's start-up; throughput per core",
    )
    parser.add_argument(
        "--replay",
        nargs="+",
        metavar="FILE",
        help="instead: `walkcap replay` of each recording (a real trial, minutes long), the "
        "whole command as a user runs it, 3 runs each: times real time, CPU time, peak memory",
    )
    parser.add_argument(
        "--stages",
        action="store_true",
        help="for --replay: instead, the CPU time a frame of each stage of the reader and the "
        "host, the replay run in one process over --frames frames (default 2000)",
    )
    parser.add_argument(
        "--scale",
        action="store_true",
        help="instead: synthesize trials of growing length (--minutes) and measure each "
        "reading command's time and peak memory on each, with the growth",
    )
    parser.add_argument(
        "--minutes",
        default="1,2,4",
        metavar="M,M,...",
        help="trial lengths for --scale, in minutes (default 1,2,4)",
    )
    parser.add_argument(
        "--trials",
        nargs="+",
        metavar="FILE",
        help="for --scale: these recorded trials instead of synthesized ones",
    )
    parser.add_argument(
        "--runs",
        type=positive("runs"),
        default=1,
        help="for --scale: runs of each command on each trial; the median and range (default 1)",
    )
    bench_corpus.add_arguments(parser)


def run(args, config) -> int:
    from capture import bench

    say = (lambda line: None) if args.json else (lambda line: print(f"… {line}", file=sys.stderr))
    if args.soak is not None:
        return _soak(bench, args.soak, args.json)
    if args.cluster:
        return bench_corpus.run(args, config)
    if args.replay and args.stages:
        return _stages(args.replay, int(args.frames) or 2000, args.json, say)
    if args.replay:
        return _replay(args.replay, args.json, say)
    if args.scale:
        return _scale(args.minutes, args.trials, int(args.runs), args.json, say)
    results = bench.run_all(args.seconds, progress=say)
    machine = bench.machine()
    if args.json:
        print(json.dumps({"machine": machine, "results": [r.to_dict() for r in results]}, indent=2))
        return 0
    print(
        f"machine: {machine['cpu']}, {machine['cores']} cores, {machine['memory_gib']} GiB, "
        f"Python {machine['python']}, torch {machine['torch']}, load {machine['load_avg_1min']}"
    )
    print(f"{'benchmark':32} {'value':>12} {'unit':10} {'goal':>12}  ")
    _print_results(results)
    return 0


def _print_results(results) -> None:
    """One line a result: its value against its goal, and whether the goal is met."""
    for r in results:
        goal = "" if r.goal is None else ("<= " if r.better == "lower" else ">= ") + f"{r.goal:g}"
        mark = {True: "ok", False: "MISSED", None: ""}[r.met]
        print(f"{r.name:32} {r.value:12.4g} {r.unit:10} {goal:>12}  {mark} {r.note}")


def _replay(files: list[str], as_json: bool, say) -> int:
    import numpy as np

    from capture.bench import Result, machine
    from capture.bench.replay import replay_trial

    results = []
    for f in files:
        say(f"replay of {f}, 3 runs")
        run = replay_trial(f)
        minutes = f"{run.frames} frames, {run.recorded_s:.0f} s recorded"
        results += [
            Result("replay_speedup", run.speedup, "x", 20, "higher", minutes),
            Result("replay_wall", float(np.median(run.wall_s)), "s", None, "lower"),
            Result(
                "replay_cpu",
                float(np.median(run.cpu_s)),
                "s",
                None,
                "lower",
                f"user + system, both processes: {run.cpu_speedup:.1f}x real time per CPU second",
            ),
            Result("replay_peak_rss", max(run.peak_rss_mib), "MiB", 600, "lower"),
        ]
    m = machine()
    if as_json:
        print(json.dumps({"machine": m, "results": [r.to_dict() for r in results]}, indent=2))
        return 0
    print(f"machine: {m['cpu']}, {m['cores']} cores, load {m['load_avg_1min']}")
    _print_results(results)
    return 0


def _stages(files: list[str], frames: int, as_json: bool, say) -> int:
    from capture.bench.replay import stage_cpu

    tables = {}
    for f in files:
        say(f"the stages of replaying {f}, {frames} frames")
        tables[f] = stage_cpu(f, frames)
    if as_json:
        out = {
            f: [{"process": p, "stage": s, "ms": v} for (p, s), v in t.items()]
            for f, t in tables.items()
        }
        print(json.dumps(out, indent=2))
        return 0
    for f, table in tables.items():
        print(f"{f}: CPU a frame, each stage ({frames} frames, one process)")
        for process in ("reader", "host"):
            rows = [(s, v) for (p, s), v in table.items() if p == process]
            for stage, ms in sorted(rows, key=lambda r: -r[1]):
                print(f"  {process:6} {stage:72} {ms:6.3f} ms")
            print(f"  {process:6} {'in all':72} {sum(v for _, v in rows):6.3f} ms")
    return 0


def _scale(minutes: str, files: list[str] | None, runs: int, as_json: bool, say) -> int:
    from capture.bench import scale
    from capture.errors import CaptureError

    trials = None
    if files:  # recorded trials, by their length
        from capture.recording.reader import open_recording

        trials = {round(open_recording(f).duration_s / 60, 1): f for f in files}
        lengths = sorted(trials)
    else:
        try:
            lengths = [float(m) for m in minutes.split(",") if m.strip()]
        except ValueError:
            raise CaptureError(f"--minutes {minutes!r}: numbers separated by commas") from None
        if not lengths or min(lengths) <= 0:
            raise CaptureError(f"--minutes {minutes!r}: lengths above 0")
    runs = scale.run(lengths, progress=say, trials=trials, runs=runs)
    if as_json:
        print(json.dumps([r.__dict__ for r in runs], indent=2))
    else:
        print("\n".join(scale.table(runs)))
    return 0 if all(r.ok for r in runs) else 1


def _known(value: float) -> float | None:
    """NaN (not measured) as None: JSON has no NaN."""
    return None if value != value else value


def _soak(bench, minutes: float, as_json: bool) -> int:
    import tempfile

    import numpy as np

    rows = []

    def sample(snap, memory, recent):
        def pct(q):  # over the frames since the last sample
            return round(float(np.percentile(recent, q)), 2) if len(recent) else None

        cam, skipped = snap.camera, bench.renderer_skipped(snap.camera)
        row = {
            "t_s": memory[0],
            "rss_mib": _known(memory[1]),
            "rig_rss_mib": _known(memory[2]),
            "frames": snap.frames,
            "latency_p50_ms": pct(50),
            "latency_p99_ms": pct(99),
            "latency_max_ms": pct(100),
            "camera_dropped": cam.dropped + cam.errors - skipped if cam else 0,
            "renderer_skipped": skipped,
            "recorder_dropped": snap.recording.dropped if snap.recording else 0,
        }
        rows.append(row)
        if not as_json:
            print("  ".join(f"{k} {v}" for k, v in row.items()), flush=True)

    with tempfile.TemporaryDirectory() as tmp:
        run = bench.session_run(45.0, 400, minutes * 60, tmp, sample_every_s=10.0, on_sample=sample)
    lat = run.latency_ms
    growth, growth_late = bench.rss_growth_mib_per_min(run.rss_mib)
    summary = {
        "minutes": minutes,
        "frames": run.frames,
        "dropped": run.dropped,
        # of those, the mock rig's renderer's (it fell behind), not the capture path's
        "renderer_skipped": run.renderer_skipped,
        "latency_p50_ms": float(np.median(lat)) if len(lat) else None,
        "latency_p99_ms": float(np.percentile(lat, 99)) if len(lat) else None,
        "latency_max_ms": float(np.max(lat)) if len(lat) else None,
        "pipeline": run.pipeline_priority,
        "rss_start_mib": run.rss_mib[0][1] if run.rss_mib else None,
        # after the first minute: what warm-up allocates is in, growth is what is left
        "rss_1min_mib": next((m for t, m, _ in run.rss_mib if t >= 60), None),
        "rss_end_mib": run.rss_mib[-1][1] if run.rss_mib else None,
        # None when the run is too short to tell (under about 2 minutes)
        "rss_growth_mib_per_min": _known(round(growth, 3)),
        "rss_growth_last_half_mib_per_min": _known(round(growth_late, 3)),
        "rig_rss_start_mib": _known(run.rss_mib[0][2]) if run.rss_mib else None,
        "rig_rss_end_mib": _known(run.rss_mib[-1][2]) if run.rss_mib else None,
        "record_mb_per_s": run.record_bytes / max(run.record_seconds, 1e-9) / 1e6,
    }
    if as_json:
        print(
            json.dumps({"machine": bench.machine(), "samples": rows, "summary": summary}, indent=2)
        )
    else:
        print(
            "summary: "
            + ", ".join(
                f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in summary.items()
            )
        )
    return 0
