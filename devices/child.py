"""A function run in a fresh Python process, joined to this one by a socket.

Used where work must not share this process's GIL: the mock rig (hardware stand-ins) and
replay's frame reader. Not multiprocessing's spawn, which re-runs the caller's main script
in the child (a plain script without a `__main__` guard would start itself again): the
child is `python -c` importing `target` ("package.module:function") and calling it with a
`multiprocessing.connection.Connection` and the pickled arguments. The child's end of the
socket closes when this process dies, so a child blocked on it ends too.
"""

from __future__ import annotations

import os
import pickle
import socket
import subprocess
import sys
from multiprocessing.connection import Connection


class Child:
    """The process and our end of the connection."""

    def __init__(self, target: str, *args, quiet: bool | None = None) -> None:
        module, _, function = target.partition(":")
        payload = pickle.dumps(args)  # before the process starts: unpicklable is our error
        host_end, child_end = socket.socketpair()
        code = (
            f"import sys; sys.path[:0] = {sys.path!r}; "
            f"from devices.child import _run; _run({module!r}, {function!r}, "
            f"{child_end.fileno()})"
        )
        if quiet is None:  # a child's stderr would garble a terminal UI
            quiet = not os.environ.get("WALKCAP_DEBUG")
        # A child is one worker beside this process: one BLAS thread. OpenBLAS otherwise
        # starts a thread per core at import (CPU spent for nothing).
        env = {"OPENBLAS_NUM_THREADS": "1", **os.environ}
        self.process = subprocess.Popen(
            [sys.executable, "-c", code],
            pass_fds=[child_end.fileno()],
            env=env,
            stdin=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL if quiet else None,
        )
        child_end.close()
        self.conn = Connection(host_end.detach())
        self.conn.send_bytes(payload)

    @property
    def pid(self) -> int:
        return self.process.pid

    def running(self) -> bool:
        return self.process.poll() is None

    def end(self, timeout_s: float = 5.0) -> None:
        """Wait for the child to exit (after it was told to), then kill it if it did not."""
        try:
            self.process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(timeout=2.0)
        self.conn.close()


def _run(module: str, function: str, fd: int) -> None:
    import importlib

    conn = Connection(fd)
    try:
        args = conn.recv()
    except (EOFError, OSError):
        return
    getattr(importlib.import_module(module), function)(conn, *args)
