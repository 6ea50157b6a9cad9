"""Corpus jobs: one task per session, trial or recording, run where the caller says.

    jobs.run(tasks, jobs.LOCAL)              here, one after the other
    jobs.run(tasks, jobs.Processes(4))       a pool of 4 fresh Python processes (spawn)
    jobs.run(tasks, jobs.Cluster("local"))   Ray tasks (capture.corpus.cluster connects)

Every way gives the tasks' results in task order, and `on_result` sees each one in that
order as soon as it and those before it are done. Here and in processes the first error
ends the job as the task raised it. On a cluster a task that fails (its function raised,
or its worker or node was lost) runs once more; if it fails again it is named on stderr
with its error, and once every other task has ended ClusterError says how many failed, so
no trial is ever silently missing.

A task is a module-level function of walkcap: a process or a cluster node imports it from
its own walkcap installation, and reads and writes files at the paths the caller gives, so
those paths must be reachable from every node (absolute, on one machine or shared storage).
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from capture.corpus import cluster
from capture.errors import CaptureError

log = logging.getLogger(__name__)

RETRIES = 1  # on a cluster a failed task runs once more (a lost node, a worker killed for memory)


@dataclass(frozen=True)
class Task:
    """One session's or trial's work: `function(*args)`."""

    name: str  # what a failure is reported by: the output or input file, the session
    function: Callable
    args: tuple = ()


@dataclass(frozen=True)
class Local:
    """In this process, one task after the other."""


@dataclass(frozen=True)
class Processes:
    """In a pool of `count` fresh Python processes on this machine."""

    count: int

    def __post_init__(self) -> None:
        if self.count < 1:
            raise CaptureError(f"processes: at least 1, got {self.count}")


@dataclass(frozen=True)
class Cluster:
    """As Ray tasks: `address` "local" starts a cluster on this machine (`cpus` cores,
    default all); any other address joins a running cluster."""

    address: str
    cpus: int | None = None


Where = Local | Processes | Cluster
LOCAL = Local()


def choose(cluster_address: str | None = None, workers: int = 1) -> Where:
    """Where the commands' `--cluster ADDRESS` and `--workers N` say: the cluster when one
    is named, else N processes, else here."""
    if cluster_address:
        return Cluster(cluster_address)
    return Processes(workers) if workers > 1 else LOCAL


def task_path(where: Where, path: str | os.PathLike) -> str:
    """A file's path as a task gets it: absolute on a cluster (a node's worker need not
    start in this folder), else as given (an error names the file as the user did)."""
    return str(Path(path).resolve()) if isinstance(where, Cluster) else str(path)


@dataclass(frozen=True)
class TaskFailure:
    name: str
    error: str


def run(
    tasks: Sequence[Task],
    where: Where = LOCAL,
    *,
    desc: str = "job",
    unit: str = "task",
    show_progress: bool | None = None,
    on_result: Callable[[int, object], None] | None = None,
    keep_results: bool = True,
) -> list:
    """The tasks' results in task order, computed `where` (see the module's text).
    `show_progress`: a bar over tasks on stderr (default: when stderr is a terminal);
    `on_result(i, result)`: called in task order as results come in; `keep_results`
    False: each result let go once on_result has had it (None in the list), for results
    too large to hold all at once."""
    from tqdm import tqdm

    tasks = list(tasks)
    if show_progress is None:
        show_progress = sys.stderr.isatty()
    if isinstance(where, Cluster):
        with cluster.connect(where.address, num_cpus=where.cpus):
            return _on_ray(tasks, desc, unit, show_progress, on_result, keep_results)
    results: list = []
    with tqdm(
        total=len(tasks), desc=desc, unit=unit, file=sys.stderr, disable=not show_progress
    ) as bar:
        for i, result in enumerate(_in_order(tasks, where)):
            if on_result is not None:
                on_result(i, result)
            results.append(result if keep_results else None)
            bar.update(1)
    return results


def _in_order(tasks: list[Task], where: Local | Processes):
    """Each task's result in task order; the first error raised as the task raised it."""
    calls = [(t.function, t.args) for t in tasks]
    if isinstance(where, Processes) and where.count > 1 and len(tasks) > 1:
        import multiprocessing as mp

        # spawn: a fresh interpreter, never a fork of this process's threads and locks
        with mp.get_context("spawn").Pool(min(where.count, len(tasks))) as pool:
            yield from pool.imap(_apply, calls)
    else:
        for call in calls:
            yield _apply(call)


def _apply(call: tuple[Callable, tuple]):
    function, args = call
    return function(*args)


def _on_ray(
    tasks: list[Task],
    desc: str,
    unit: str,
    show_progress: bool,
    on_result: Callable[[int, object], None] | None,
    keep_results: bool = True,
) -> list:
    """The tasks on the connected Ray cluster; errors are caught in the worker, so a
    failure is one line, not Ray's traceback."""
    import ray
    from tqdm import tqdm

    remote = ray.remote(max_retries=0, num_cpus=1)(_call)

    def submit(i: int):
        return remote.options(name=tasks[i].name).remote(tasks[i].function, *tasks[i].args)

    index = {submit(i): i for i in range(len(tasks))}
    attempts = [1] * len(tasks)
    results: list = [None] * len(tasks)
    ended = [False] * len(tasks)
    succeeded = [False] * len(tasks)
    failures: list[TaskFailure] = []
    said = 0  # results up to here have gone to on_result (or failed)
    try:
        with tqdm(
            total=len(tasks), desc=desc, unit=unit, file=sys.stderr, disable=not show_progress
        ) as bar:
            while index:
                done, _ = ray.wait(list(index), num_returns=1)
                for ref in done:
                    i = index.pop(ref)
                    try:
                        ok, value = ray.get(ref)
                    except ray.exceptions.RayError as e:  # the worker or its node was lost
                        ok, value = False, cluster.describe(e)
                    if ok:
                        results[i], succeeded[i] = value, True
                    elif attempts[i] <= RETRIES:
                        attempts[i] += 1
                        log.info("%s failed (%s); running it again", tasks[i].name, value)
                        index[submit(i)] = i
                        continue
                    else:
                        failures.append(TaskFailure(tasks[i].name, value))
                        tqdm.write(f"{tasks[i].name}: failed: {value}", file=sys.stderr)
                    ended[i] = True
                    bar.update(1)
                while said < len(tasks) and ended[said]:
                    if on_result is not None and succeeded[said]:
                        on_result(said, results[said])
                    if not keep_results:
                        results[said] = None
                    said += 1
    except KeyboardInterrupt:
        for ref in index:
            ray.cancel(ref, force=True)
        raise
    if failures:
        names = ", ".join(f.name for f in failures)
        raise cluster.ClusterError(
            f"{len(failures)} of {len(tasks)} {unit}s failed ({RETRIES + 1} attempts "
            f"each): {names}",
            results,
        )
    return results


def _call(function: Callable, *args) -> tuple[bool, object]:
    """(True, the result) or (False, the error in one line; its traceback in the worker's
    log with WALKCAP_DEBUG)."""
    try:
        return True, function(*args)
    except Exception as e:
        if os.environ.get("WALKCAP_DEBUG"):
            log.exception("task failed")
        return False, cluster.describe(e)
