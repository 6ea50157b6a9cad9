"""`walkcap bench --replay`: the whole command measured in a fresh process each run."""

import sys

import pytest

from capture.bench.replay import replay_trial
from capture.errors import CaptureError
from capture.recording.reader import open_recording
from tests.recording_fixtures import write_recording

# Stands in for `walkcap`: takes `replay FILE -o OUT`, holds 64 MiB, writes OUT.
STAND_IN = (
    "import sys; block = bytearray(64 << 20); block[::4096] = b'x' * len(block[::4096]); "
    "open(sys.argv[sys.argv.index('-o') + 1], 'wb').write(b'replayed')"
)


def test_each_run_is_measured_in_its_own_process(tmp_path):
    path = tmp_path / "trial.mcap"
    write_recording(path, seconds=2.0)
    rec = open_recording(path)
    run = replay_trial(path, runs=2, command=[sys.executable, "-c", STAND_IN])
    assert run.frames == rec.topics["/camera/depth"].count > 0
    assert run.recorded_s == rec.duration_s
    assert len(run.wall_s) == len(run.cpu_s) == len(run.peak_rss_mib) == 2
    assert min(run.peak_rss_mib) >= 64  # the stand-in's memory is its own, not this one's
    assert all(c > 0 for c in run.cpu_s) and run.speedup > 0 and run.cpu_speedup > 0


def test_a_failed_replay_is_one_line_with_its_reason(tmp_path):
    path = tmp_path / "trial.mcap"
    write_recording(path, seconds=1.0)
    failing = [sys.executable, "-c", "import sys; sys.exit('replay: the disk is full')"]
    with pytest.raises(CaptureError, match="failed: replay: the disk is full"):
        replay_trial(path, runs=1, command=failing)


@pytest.mark.slow
@pytest.mark.subprocess
def test_the_bench_replays_a_synthesized_trial_as_a_user_does(tmp_path):
    from capture import bench

    speedup, cpu = bench.replay_results(str(tmp_path), minutes=0.05, runs=1)
    assert speedup.name == "replay_speedup" and speedup.value > 0 and speedup.goal == 20
    assert "135 frames at 45 fps" in speedup.note
    assert cpu.value > 0 and not list(tmp_path.glob("*.mcap"))


@pytest.mark.subprocess
def test_a_command_is_measured_without_the_memory_of_the_process_that_starts_it():
    from capture.bench.launch import measured

    held = bytearray(200 << 20)  # this process: over 200 MiB resident
    held[::4096] = b"x" * len(held[::4096])
    holds_64_mib = "block = bytearray(64 << 20); block[::4096] = b'x' * len(block[::4096])"
    run = measured([sys.executable, "-c", holds_64_mib])
    assert run.returncode == 0 and run.cpu_s > 0 and len(held) == 200 << 20
    assert 64 <= run.peak_mib < 120


def test_the_stages_of_a_replay_are_each_timed(tmp_path):
    from capture.bench.replay import STAGES, stage_cpu

    path = tmp_path / "trial.mcap"
    write_recording(path, seconds=2.0)
    stages = stage_cpu(path, frames=40, skip=20)
    named = {(process, name) for process, name, _, _ in STAGES}
    assert named <= stages.keys()
    assert {p for p, _ in stages} == {"reader", "host"} and len(stages) == len(named) + 3
    timed = [
        ("reader", "preprocessing"),
        ("reader", "fitting the profile"),
        ("host", "CNN, batches of 16"),
        ("host", "writer: compression (zstd)"),
        ("reader", "sending (packing)"),
        ("host", "receiving (unpacking)"),
    ]
    assert all(stages[key] > 0 for key in timed), stages
    assert all(ms < 1000 for ms in stages.values())  # a frame's share, not the run's
