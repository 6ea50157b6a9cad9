"""`walkcap bench --cluster ADDRESS|local`: corpus jobs on the cluster against this process.

Each round runs, as a user would, `walkcap synth` (dataset) and `walkcap replay` of the
same sessions three ways: in one process as the command runs by default, in one process
held to one core (the per-core baseline), and with `--cluster`, rotating which goes first
(the machine may be shared: interleaving spreads its load over all). Each run is a fresh
`walkcap` process, so the cluster's figure includes starting it; that start-up is also
measured alone (connect, then one no-op task per CPU). Reported: each run's seconds and
the machine's busy CPU seconds meanwhile, the median and range per side, the speed-ups,
and throughput per core.

One process is not one core: synth's ray casts run on every core the process may use, and
replay reads in a second process. The speed-up over the default path is bounded by the
cores that path leaves idle; the speed-up over one core is how the cluster scales.
"""

from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from capture.errors import CaptureError

SIDES = ("one", "one_core", "cluster")
JOBS = ("synth", "replay")


def _env() -> dict:
    """This environment, with the walkcap this process runs first on the path."""
    root = str(Path(__file__).resolve().parents[2])
    path = os.environ.get("PYTHONPATH", "")
    return {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (root, path) if p)}


def hold_to_one_core() -> None:
    """In the child before it starts: this process and its children on one core."""
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})


def _busy_cpu_s() -> float:
    """CPU seconds this machine has spent busy since boot, all processes (/proc/stat): Ray's
    processes are not the command's children, so only the machine's count sees them."""
    try:
        with open("/proc/stat") as f:
            ticks = [int(v) for v in f.readline().split()[1:]]
    except (OSError, ValueError):
        return float("nan")
    idle = ticks[3] + (ticks[4] if len(ticks) > 4 else 0)  # idle and iowait
    return (sum(ticks[:8]) - idle) / os.sysconf("SC_CLK_TCK")


def _walkcap(*argv: str, one_core: bool = False) -> tuple[float, float]:
    """(seconds, CPU seconds the machine spent meanwhile) that `walkcap argv` takes, as its
    own process; its errors are ours. The CPU count includes whatever else runs here."""
    t = time.perf_counter()
    before = _busy_cpu_s()
    done = subprocess.run(
        [sys.executable, "-m", "tui.cli", *argv],
        capture_output=True,
        text=True,
        check=False,
        env=_env(),
        preexec_fn=hold_to_one_core if one_core else None,
    )
    seconds = time.perf_counter() - t
    cpu = _busy_cpu_s() - before
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise CaptureError(f"walkcap {argv[0]} failed during the benchmark: {last}")
    return seconds, cpu


def _startup(address: str) -> dict:
    """Seconds to start (or join) the cluster, and for a no-op task on each CPU to return
    (the workers' start), in a fresh process as the commands pay them."""
    code = (
        "import time, json; t = time.perf_counter()\n"
        "from capture.corpus import cluster, jobs\n"
        f"with cluster.connect({address!r}) as r:\n"
        "    up = time.perf_counter() - t\n"
        "    n = int(r.get('CPU', 1))\n"
        "    jobs.run([jobs.Task(str(i), time.sleep, (0.2,)) for i in range(n)],"
        f" jobs.Cluster({address!r}), show_progress=False)\n"
        "    warm = time.perf_counter() - t - up - 0.2\n"
        "print(json.dumps({'connect_s': up, 'workers_s': warm, 'total_s':"
        " time.perf_counter() - t}))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=_env())
    if done.returncode != 0:
        raise CaptureError(f"the cluster did not start: {done.stderr.strip().splitlines()[-1:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _frames(folder: Path, suffix: str) -> int:
    if suffix == ".npz":
        from inference.dataset import read_session

        return sum(len(read_session(p)) for p in folder.glob("*.npz"))
    from capture.recording.reader import open_recording
    from capture.recording.topics import DEPTH

    return sum(open_recording(p).topics[DEPTH].count for p in folder.glob("*.replay.mcap"))


def run(address: str, sessions: int, rounds: int, frames: int = 0, progress=print) -> dict:
    """The benchmark's rounds against the cluster at `address`; the report (`report`)."""
    from capture import bench

    n = str(sessions)
    frame_flags = ["--frames", str(frames)] if frames else []
    cores = os.cpu_count() or 1
    if not hasattr(os, "sched_setaffinity"):
        raise CaptureError("bench --cluster needs a system that can hold a process to one core")
    times: dict[str, dict[str, list[float]]] = {job: {side: [] for side in SIDES} for job in JOBS}
    cpu: dict[str, dict[str, list[float]]] = {job: {side: [] for side in SIDES} for job in JOBS}
    load = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory(prefix="walkcap-bench-") as tmp:
        tmp = Path(tmp)
        progress(f"{sessions} recordings to replay (synth --format recording, on the cluster)")
        _walkcap("synth", "--format", "recording", "--out", str(tmp / "rec"), "--sessions", n,
                 *frame_flags, "--cluster", address)  # fmt: skip
        recordings = sorted(str(p) for p in (tmp / "rec").glob("*.mcap"))
        startups = []
        for r in range(rounds):
            order = SIDES[r % 3 :] + SIDES[: r % 3]
            for job in JOBS:
                for side in order:
                    out = tmp / f"{job}-{side}"
                    shutil.rmtree(out, ignore_errors=True)
                    extra = ["--cluster", address] if side == "cluster" else []
                    if job == "synth":
                        argv = ["synth", "--out", str(out), "--sessions", n, *frame_flags, *extra]
                    else:
                        argv = ["replay", *recordings, "-o", str(out), *extra]
                    seconds, used = _walkcap(*argv, one_core=side == "one_core")
                    times[job][side].append(seconds)
                    cpu[job][side].append(used)
                    load.append(os.getloadavg()[0])
                    progress(f"round {r + 1}: {job} {side}: {seconds:.1f} s, {used:.1f} CPU s")
            startups.append(_startup(address))
            progress(f"round {r + 1}: cluster start-up {startups[-1]['total_s']:.1f} s")
        counted = {
            "synth": _frames(tmp / "synth-one", ".npz"),
            "replay": _frames(tmp / "replay-one", ".mcap"),
        }
    return report(sessions, cores, times, cpu, counted, startups, load, bench.machine())


def _spread(values: list[float]) -> dict:
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


def report(sessions, cores, times, cpu, frames, startups, load, machine) -> dict:
    start = statistics.median(s["total_s"] for s in startups)
    jobs = {}
    for job, sides in times.items():
        one, core, clu = (statistics.median(sides[side]) for side in SIDES)
        jobs[job] = {
            "sessions": sessions,
            "frames": frames[job],
            **{
                f"{side}_s": {
                    **_spread(sides[side]),
                    "runs": sides[side],
                    "cpu_s_median": statistics.median(cpu[job][side]),
                }
                for side in SIDES
            },
            # the default path already uses more than one core (module doc)
            "one_cores_used": statistics.median(
                c / s for c, s in zip(cpu[job]["one"], sides["one"])
            ),
            "speedup": one / clu,
            "speedup_over_one_core": core / clu,
            "speedup_without_startup": one / max(clu - start, 1e-9),
            "speedup_over_one_core_without_startup": core / max(clu - start, 1e-9),
            # per core of the cluster, start-up included
            "cluster_sessions_per_min_per_core": sessions / (clu / 60) / cores,
            "cluster_frames_per_s_per_core": frames[job] / clu / cores,
            "one_core_sessions_per_min": sessions / (core / 60),
            "one_core_frames_per_s": frames[job] / core,
            "one_process_sessions_per_min": sessions / (one / 60),
            "one_process_frames_per_s": frames[job] / one,
        }
    return {
        "machine": machine,
        "cores": cores,
        "load_avg_1min": {"start": load[0], "max": max(load), "end": load[-1]},
        "startup_s": {
            **_spread([s["total_s"] for s in startups]),
            "connect_median": statistics.median(s["connect_s"] for s in startups),
            "workers_median": statistics.median(s["workers_s"] for s in startups),
        },
        "jobs": jobs,
    }
