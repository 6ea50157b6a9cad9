"""`walkcap bench --cluster` (capture.bench.cluster): its arithmetic and its one-core
baseline."""

import os
import subprocess
import sys

import pytest

from capture.bench import cluster


def _times(one, core, clu):
    return {"one": [one], "one_core": [core], "cluster": [clu]}


def example_report() -> dict:
    """A report of two jobs on 2 cores with a 5 s cluster start-up."""
    times = {"synth": _times(30.0, 50.0, 25.0), "replay": _times(20.0, 36.0, 18.0)}
    cpu = {"synth": _times(39.0, 50.0, 55.0), "replay": _times(36.0, 36.0, 40.0)}
    startups = [{"total_s": 5.0, "connect_s": 3.0, "workers_s": 0.5}]
    return cluster.report(
        16, 2, times, cpu, {"synth": 5200, "replay": 5300}, startups, [0.1, 0.5], {"cpu": "x"}
    )


def test_report_gives_both_speedups_and_the_cores_the_default_path_uses():
    synth = example_report()["jobs"]["synth"]
    assert synth["speedup"] == pytest.approx(30 / 25)
    assert synth["speedup_over_one_core"] == pytest.approx(50 / 25)
    assert synth["speedup_without_startup"] == pytest.approx(30 / 20)
    assert synth["speedup_over_one_core_without_startup"] == pytest.approx(50 / 20)
    assert synth["one_cores_used"] == pytest.approx(1.3)
    assert synth["cluster_frames_per_s_per_core"] == pytest.approx(5200 / 25 / 2)
    assert synth["one_core_sessions_per_min"] == pytest.approx(16 / (50 / 60))


@pytest.mark.subprocess
@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinity here")
def test_the_one_core_baseline_runs_on_one_core():
    code = "import os; print(len(os.sched_getaffinity(0)))"
    done = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        preexec_fn=cluster.hold_to_one_core,
    )
    assert done.stdout.strip() == "1"


def test_the_simulators_casts_use_the_cores_the_process_may_run_on(monkeypatch):
    from devices.simulator import render

    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    assert render._threads_allowed() == len(os.sched_getaffinity(0))
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    assert render._threads_allowed() == 1


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinity here")
def test_each_round_runs_every_side_of_both_jobs_first_in_turn(monkeypatch):
    import capture.bench

    runs = []

    def walkcap(*argv, one_core=False):
        runs.append((argv[0], "--cluster" in argv, one_core))
        return 2.0, 3.0

    monkeypatch.setattr(cluster, "_walkcap", walkcap)
    monkeypatch.setattr(
        cluster, "_startup", lambda a: {"total_s": 1, "connect_s": 1, "workers_s": 0}
    )
    monkeypatch.setattr(cluster, "_frames", lambda folder, suffix: 100)
    monkeypatch.setattr(capture.bench, "machine", lambda: {"cpu": "x"})
    report = cluster.run("local", sessions=4, rounds=2, progress=lambda line: None)
    assert runs[0] == ("synth", True, False)  # the recordings to replay, on the cluster
    first_round, second_round = runs[1:7], runs[7:13]
    assert [r[0] for r in first_round] == ["synth"] * 3 + ["replay"] * 3
    assert first_round[:3] == [
        ("synth", False, False),
        ("synth", False, True),
        ("synth", True, False),
    ]
    assert second_round[0] == ("synth", False, True)  # the next side goes first
    assert report["jobs"]["replay"]["frames"] == 100 and report["jobs"]["synth"]["speedup"] == 1.0
