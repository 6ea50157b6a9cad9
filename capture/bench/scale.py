"""`walkcap bench --scale`: what reading a trial costs as the trial grows.

Synthesizes trials of growing length (every topic a session writes, 45 fps, 100 Hz IMU,
written with a blocking recorder so that nothing is shed), or takes recorded ones, runs
each reading command on each in a fresh process, one at a time, and reports its wall
time, CPU time (user + system, its children included: steadier than wall time on a shared
machine) and peak memory (the largest resident set of the process and its children), the
median of a few runs, with the growth from the shortest trial: flat memory and linear time
are ratios of 1 and of the length ratio.

    walkcap bench --scale --minutes 1,4,16
"""

from __future__ import annotations

import dataclasses
import os
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

FPS = 45.0
IMU_HZ = 100.0
T0 = 1_000_000_000_000  # 1000 s on the session clock

# the replay screen (`walkcap replay --tui`) without a terminal: the trial loaded, then
# played through a second at a time, as the screen asks for it
SCREEN = """
import sys
from tui.replay import ReplaySource
src = ReplaySource(sys.argv[1], clock=lambda: 0, play=False)
src.start()
while src.position()[0] < src.duration_s:
    src.seek(1.0)
    src.snapshot()
"""
# the Python API's per-frame table of the trial
FRAME_TABLE = """
import sys
from capture.recording.reader import frame_table, open_recording
frame_table(open_recording(sys.argv[1]))
"""
WALKCAP = ["-m", "tui.cli"]
# (name, the Python arguments; FILE and CUT are filled in, and OUT in the paths it begins)
COMMANDS = (
    ("info", [*WALKCAP, "info", "FILE"]),
    ("export parquet", [*WALKCAP, "export", "FILE", "--quiet", "-o", "OUT"]),
    ("export csv", [*WALKCAP, "export", "FILE", "--quiet", "--format", "csv", "-o", "OUT"]),
    ("export mat", [*WALKCAP, "export", "FILE", "--quiet", "--format", "mat", "-o", "OUT"]),
    ("recover (60 % cut)", [*WALKCAP, "recover", "CUT", "-o", "OUT/recovered.mcap"]),
    ("replay", [*WALKCAP, "replay", "FILE", "-o", "OUT/replay.mcap"]),
    ("eval recordings", [*WALKCAP, "eval", "recordings", "FILE", "--json"]),
    ("replay --tui screen", ["-c", SCREEN, "FILE"]),
    ("Python API frame table", ["-c", FRAME_TABLE, "FILE"]),
)


def synthesize(
    path: str | os.PathLike,
    minutes: float,
    seed: int = 0,
    session: dict | None = None,
    depth: bool = True,
) -> Path:
    """A mock trial of `minutes` at 45 fps: depth, cloud, image, CNN, fused decision,
    features, truth, IMU, a label change every 5 s. Frames cycle through a few synthetic
    ones (devices.simulator.synthetic): the sizes and rates of a trial, quickly. `session`:
    its session metadata (default subject B01, indoor, trial 1); `depth` False: no depth
    frames and no clouds (a trial's tables at a fraction of its bytes, for the readers of
    tables: export, eval, the frame table)."""
    from capture.recording.writer import Recorder
    from devices.frames import MODES, ImuSample
    from devices.simulator.synthetic import synthetic_frame

    frames = [synthetic_frame(i, 0, seed=seed) for i in range(24)]
    metadata = {
        "session": session or {"subject": "B01", "condition": "indoor", "trial": 1},
        "devices": {"camera_backend": "mock", "camera_fps": FPS, "imu_rate_hz": IMU_HZ},
    }
    rec = Recorder(path, metadata=metadata, blocking=True, queue_size=4096)
    rec.start()
    n = int(minutes * 60 * FPS)
    k_imu = 0
    quaternion = np.array([0.9, 0.1, -0.2, 0.3]) / np.linalg.norm([0.9, 0.1, -0.2, 0.3])
    cloud = np.column_stack([np.linspace(0.0, 1.5, 600), np.zeros(600), np.full(600, -0.55)])
    image = np.zeros((100, 100), np.uint8)
    for i in range(n):
        t = T0 + int(round(i * 1e9 / FPS))
        while T0 + k_imu * 1e9 / IMU_HZ <= t:
            ti = T0 + int(round(k_imu * 1e9 / IMU_HZ))
            rec.write_imu(
                ImuSample(
                    host_time_ns=ti + 1_000_000,
                    time_ns=ti,
                    packet_counter=k_imu % 65536,
                    sample_time_fine=k_imu * 100,
                    quaternion=quaternion,
                    acceleration=np.array([0.1, -0.2, 9.81]),
                    rate_of_turn=np.array([0.01, 0.02, -0.03]),
                    status_word=3,
                )
            )
            k_imu += 1
        mode = MODES[(i // 225) % len(MODES)]
        if i % 225 == 0:
            rec.write_label(t + 1, mode, "operator")
        frame = dataclasses.replace(
            frames[i % len(frames)], index=i, device_time_ns=t, host_time_ns=t + 3_000_000
        )
        if depth:
            rec.write_frame(frame)
        image[:] = 0
        image[50 + i % 20 :, :] = 1
        shown = cloud if depth else cloud[:0]
        rec.write_processed(i, t, t + 3_000_000, shown, image, quaternion, "")
        p = np.full(len(MODES), 0.05)
        p[MODES.index(mode)] = 0.8
        fused = {"frame_index": max(0, i - 1), "decision": mode, "posterior": p}
        rec.write_inference(i, t, t + 9_000_000, p, fused)
        rec.write_features(i, t, {"kind": "level", "slope_deg": 0.5, "riser_m": None})
        rec.write_truth(i, t, {"mode": mode})
    rec.close()
    return Path(path)


@dataclass
class Run:
    command: str
    minutes: float
    seconds: float  # the median of the runs
    peak_mib: float
    ok: bool
    cpu_s: float = float("nan")
    seconds_range: tuple[float, float] = (float("nan"), float("nan"))
    cpu_range: tuple[float, float] = (float("nan"), float("nan"))
    peak_range: tuple[float, float] = (float("nan"), float("nan"))


def measure(argv: list[str]) -> tuple[float, float, float, bool]:
    """(wall s, CPU s, peak resident MiB, exit 0) of `python argv` in a fresh process, its
    children included (capture.bench.launch)."""
    from capture.bench.launch import measured

    run = measured([sys.executable, *argv])
    return run.wall_s, run.cpu_s, run.peak_mib, run.returncode == 0


def cut_copy(path: Path, out: Path, fraction: float = 0.6) -> Path:
    """The first `fraction` of a file: a trial cut off by a crash."""
    with open(path, "rb") as src, open(out, "wb") as dst:
        left = int(path.stat().st_size * fraction)
        while left > 0:
            block = src.read(min(left, 1 << 24))
            if not block:
                break
            dst.write(block)
            left -= len(block)
    return out


def run(
    minutes: list[float],
    folder: str | None = None,
    progress=print,
    *,
    trials: dict[float, Path] | None = None,
    runs: int = 1,
    commands: list[str] | None = None,
) -> list[Run]:
    """Each command on a trial of each length, one command at a time, `runs` times (the
    runs of a command on a trial one after another). `trials`: recorded trials by length
    in minutes, used instead of synthesized ones; `commands`: the names of COMMANDS run
    (default all)."""
    chosen = [(n, a) for n, a in COMMANDS if commands is None or n in commands]
    out_runs: list[Run] = []
    with tempfile.TemporaryDirectory(dir=folder) as tmp:
        work = Path(tmp)
        for m in sorted(minutes):
            if trials is not None:
                trial, made = Path(trials[m]), False
            else:
                progress(f"synthesizing a {m:g}-minute trial")
                trial, made = synthesize(work / f"B01_indoor_t01_{m:g}min.mcap", m), True
            cut = cut_copy(trial, work / f"cut_{m:g}min.mcap")
            for name, args in chosen:
                out = work / "out"
                figures = []
                for k in range(runs):
                    out.mkdir(exist_ok=True)
                    argv = [
                        str(trial) if a == "FILE" else str(cut) if a == "CUT" else a
                        for a in (str(out) + x[3:] if x.startswith("OUT") else x for x in args)
                    ]
                    progress(
                        f"{name} on {m:g} min" + (f", run {k + 1} of {runs}" if runs > 1 else "")
                    )
                    figures.append(measure(argv))
                    for p in sorted(out.rglob("*"), reverse=True):
                        p.unlink() if p.is_file() else p.rmdir()
                out_runs.append(_run_of(name, m, figures))
            if made:
                trial.unlink()
            cut.unlink()
    return out_runs


def _run_of(name: str, minutes: float, figures: list[tuple[float, float, float, bool]]) -> Run:
    wall, cpu, peak, ok = (np.array([f[k] for f in figures]) for k in range(4))
    return Run(
        name,
        minutes,
        float(np.median(wall)),
        float(np.median(peak)),
        bool(ok.all()),
        float(np.median(cpu)),
        (float(wall.min()), float(wall.max())),
        (float(cpu.min()), float(cpu.max())),
        (float(peak.min()), float(peak.max())),
    )


def table(runs: list[Run]) -> list[str]:
    """Markdown: per command and length, wall time, CPU time and peak memory (medians, with
    their range when there were several runs); the growth from the shortest length."""
    lengths = sorted({r.minutes for r in runs})
    head = "| command | " + " | ".join(f"{m:g} min" for m in lengths)
    head += f" | growth {lengths[0]:g} -> {lengths[-1]:g} min (time, memory) |"
    lines = [head, "|---" * (len(lengths) + 2) + "|"]
    for name, _ in COMMANDS:
        rows = {r.minutes: r for r in runs if r.command == name}
        if not rows:
            continue
        cells = [_cell(rows[m]) if m in rows else "" for m in lengths]
        a, b = rows.get(lengths[0]), rows.get(lengths[-1])
        growth = f"{b.seconds / a.seconds:.2f}x, {b.peak_mib / a.peak_mib:.2f}x" if a and b else ""
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {growth} |")
    return lines


def _cell(r: Run) -> str:
    low, high = r.seconds_range
    several = low == low and high == high and low != high  # known (not NaN) and apart
    wall = f"{r.seconds:.1f} s" + (
        f" ({r.seconds_range[0]:.1f}-{r.seconds_range[1]:.1f})" if several else ""
    )
    cpu = "" if r.cpu_s != r.cpu_s else f", {r.cpu_s:.1f} s CPU"
    low_peak, high_peak = (f"{v:.0f}" for v in r.peak_range)
    peak = f", {r.peak_mib:.0f} MiB" + (
        f" ({low_peak}-{high_peak})" if several and low_peak != high_peak else ""
    )
    return wall + cpu + peak + ("" if r.ok else " (failed)")
