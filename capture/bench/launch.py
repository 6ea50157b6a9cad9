"""A command measured as a user runs it: wall time, CPU time and peak memory of a fresh
process and the processes it waits for.

The command is started by a small launcher (Python without site packages, a few MiB) that
forks, runs it and reports its resource use: a process's peak resident set counts the
memory of the process that forked it, so a command forked straight from the bench would
report at least the bench's own size.
"""

from __future__ import annotations

import subprocess
import sys
import time
from dataclasses import dataclass

_LAUNCHER = """
import os, sys
pid = os.fork()
if pid == 0:
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)
    os.execv(sys.argv[1], sys.argv[1:])
_, status, usage = os.wait4(pid, 0)
print(os.waitstatus_to_exitcode(status), usage.ru_utime + usage.ru_stime, usage.ru_maxrss)
"""


@dataclass
class Measured:
    wall_s: float
    cpu_s: float  # user + system, the processes it waited for included
    peak_mib: float  # the largest resident set of it and the processes it waited for
    returncode: int


def measured(argv: list[str], stderr=subprocess.DEVNULL) -> Measured:
    """`argv` (a program and its arguments) run once; its output to nothing, its errors
    to `stderr` (a file or DEVNULL)."""
    start = time.perf_counter()
    launcher = subprocess.run(
        [sys.executable, "-S", "-c", _LAUNCHER, *argv],
        stdout=subprocess.PIPE,
        stderr=stderr,
        text=True,
        check=True,
    )
    wall = time.perf_counter() - start
    code, cpu, peak_kib = launcher.stdout.split()
    return Measured(wall, float(cpu), int(peak_kib) / 1024, int(code))
