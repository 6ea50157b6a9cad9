"""`walkcap bench --cluster ADDRESS|local`: the arguments and the printed report of the
cluster benchmark (capture.bench.cluster)."""

from __future__ import annotations

import json
import sys

from tui.commands import count


def add_arguments(parser) -> None:
    parser.add_argument(
        "--sessions", type=count(2), default=16, metavar="N", help="sessions (default 16)"
    )
    parser.add_argument(
        "--rounds", type=count(1), default=2, metavar="N", help="A/B rounds (default 2)"
    )
    parser.add_argument(
        "--frames",
        type=count(0),
        default=0,
        metavar="N",
        help="at most N frames a session (--cluster); frames measured (--replay --stages)",
    )


def run(args, config) -> int:
    from capture.bench import cluster

    say = lambda line: print(f"… {line}", file=sys.stderr, flush=True)  # noqa: E731
    report = cluster.run(args.cluster, args.sessions, args.rounds, args.frames, progress=say)
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(_format(report))
    return 0


def _format(r: dict) -> str:
    s = r["startup_s"]
    lines = [
        f"machine: {r['machine']['cpu']}, {r['cores']} cores; load average (1 min) "
        f"{r['load_avg_1min']['start']:.1f} at the start, {r['load_avg_1min']['max']:.1f} at "
        f"most, {r['load_avg_1min']['end']:.1f} at the end",
        f"cluster start-up: {s['median']:.1f} s median ({s['min']:.1f}-{s['max']:.1f}): "
        f"connect {s['connect_median']:.1f} s, workers {s['workers_median']:.1f} s",
    ]
    for job, j in r["jobs"].items():
        one, core, clu = j["one_s"], j["one_core_s"], j["cluster_s"]
        lines += [
            f"{job}: {j['sessions']} sessions, {j['frames']} frames",
            f"  one process  {one['median']:6.1f} s median ({one['min']:.1f}-{one['max']:.1f}), "
            f"{j['one_process_sessions_per_min']:.1f} sessions/min, "
            f"{j['one_process_frames_per_s']:.0f} frames/s, on {j['one_cores_used']:.2f} cores",
            f"  one core     {core['median']:6.1f} s median ({core['min']:.1f}-{core['max']:.1f}),"
            f" {j['one_core_sessions_per_min']:.1f} sessions/min, "
            f"{j['one_core_frames_per_s']:.0f} frames/s",
            f"  cluster      {clu['median']:6.1f} s median ({clu['min']:.1f}-{clu['max']:.1f}), "
            f"{j['cluster_sessions_per_min_per_core']:.1f} sessions/min and "
            f"{j['cluster_frames_per_s_per_core']:.0f} frames/s per core",
            f"  speed-up     {j['speedup']:.2f}x over one process "
            f"({j['speedup_without_startup']:.2f}x without the start-up), "
            f"{j['speedup_over_one_core']:.2f}x over one core "
            f"({j['speedup_over_one_core_without_startup']:.2f}x without)",
        ]
    return "\n".join(lines)
