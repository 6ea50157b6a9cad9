"""jobs.run here and in processes: results in task order, errors as the task raised them,
and `walkcap synth --workers N --format recording` writing what one process writes."""

from __future__ import annotations

import os

import pytest

from capture.corpus import jobs
from capture.errors import CaptureError
from tests.recording_fixtures import decoded_messages
from tui.cli import main

# a pool of processes spawns Python processes that import walkcap
WHERE = [jobs.LOCAL, pytest.param(jobs.Processes(2), marks=pytest.mark.subprocess)]


def _square_with_pid(x: int) -> tuple[int, int]:
    return x * x, os.getpid()


def _refuse_three(x: int) -> int:
    if x == 3:
        raise CaptureError(f"trial {x}: damaged")
    return x


def test_choose_follows_the_flags():
    assert jobs.choose() == jobs.LOCAL
    assert jobs.choose(None, 1) == jobs.LOCAL
    assert jobs.choose(None, 3) == jobs.Processes(3)
    assert jobs.choose("local", 3) == jobs.Cluster("local")
    with pytest.raises(CaptureError, match="at least 1"):
        jobs.Processes(0)


def test_task_paths_are_absolute_only_on_a_cluster(tmp_path):
    assert jobs.task_path(jobs.LOCAL, "a/b.mcap") == "a/b.mcap"
    assert jobs.task_path(jobs.Processes(2), "a/b.mcap") == "a/b.mcap"
    assert jobs.task_path(jobs.Cluster("local"), "a/b.mcap") == str(tmp_path / "a" / "b.mcap")


@pytest.mark.parametrize("where", WHERE, ids=["local", "processes"])
def test_results_come_in_task_order(where):
    tasks = [jobs.Task(f"t{i}", _square_with_pid, (i,)) for i in range(5)]
    said = []
    results = jobs.run(tasks, where, on_result=lambda i, r: said.append((i, r[0])))
    assert [r[0] for r in results] == [0, 1, 4, 9, 16]
    assert said == [(i, i * i) for i in range(5)]
    pids = {pid for _, pid in results}
    if isinstance(where, jobs.Processes):
        assert os.getpid() not in pids and 1 <= len(pids) <= 2
    else:
        assert pids == {os.getpid()}


def test_results_too_large_to_hold_go_to_on_result_and_are_let_go():
    tasks = [jobs.Task(f"t{i}", _square_with_pid, (i,)) for i in range(4)]
    said = []
    results = jobs.run(tasks, on_result=lambda i, r: said.append(r[0]), keep_results=False)
    assert said == [0, 1, 4, 9] and results == [None] * 4


@pytest.mark.parametrize("where", WHERE, ids=["local", "processes"])
def test_the_first_error_ends_the_job_as_raised(where):
    said = []
    tasks = [jobs.Task(f"t{i}", _refuse_three, (i,)) for i in range(1, 6)]
    with pytest.raises(CaptureError, match="trial 3: damaged"):
        jobs.run(tasks, where, on_result=lambda i, r: said.append(r))
    assert said == [1, 2]


@pytest.mark.slow  # two spawned processes import walkcap and load the model: ~8 s of CPU
@pytest.mark.subprocess
def test_synth_recordings_with_workers_are_the_recordings_of_one_process(tmp_path, capsys):
    args = ["synth", "--format", "recording", "--sessions", "2", "--frames", "3"]
    assert main([*args, "--out", str(tmp_path / "one")]) == 0
    one_out = capsys.readouterr().out.split()
    assert main([*args, "--out", str(tmp_path / "two"), "--workers", "2"]) == 0
    two_out = capsys.readouterr().out.split()
    names = sorted(p.name for p in (tmp_path / "one").glob("*.mcap"))
    assert len(names) == 2
    assert sorted(p.name for p in (tmp_path / "two").glob("*.mcap")) == names
    # each written file's path, in session order, whichever process wrote it
    assert [p.split("/")[-1] for p in two_out] == [p.split("/")[-1] for p in one_out]
    for name in names:
        one = decoded_messages(tmp_path / "one" / name, relative=True)
        two = decoded_messages(tmp_path / "two" / name, relative=True)
        assert one["/camera/depth"] and one == two
