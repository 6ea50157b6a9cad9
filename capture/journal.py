"""The journal: labels and operator markers appended beside the recording, on disk at once.

The MCAP file reaches the disk a chunk at a time (about once a second); the operator's
labels must survive anything, so each one is also appended as a line of JSON to
`<recording>.journal.jsonl` and fsync'ed before the call returns. `walkcap recover` merges
the journal back into the recording. A crash can cut only the last line, which the reader
skips.
"""

from __future__ import annotations

import json
import logging
import os
import threading
from pathlib import Path

log = logging.getLogger(__name__)

SUFFIX = ".journal.jsonl"


def journal_path(recording: str | os.PathLike) -> Path:
    return Path(str(recording) + SUFFIX)


def fsync_directory(path: str | os.PathLike) -> None:
    """Make a new file's directory entry durable too (a power loss could lose the name)."""
    try:
        fd = os.open(os.fspath(path), os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


class Journal:
    """Append-only JSON lines, each written with one write() and fsync'ed. Thread-safe."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self._lock = threading.Lock()
        self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        fsync_directory(self.path.parent)
        self.entries = 0

    def append(self, entry: dict) -> None:
        """Write one entry and return once it is on disk. Raises OSError if it could not be."""
        line = (json.dumps(entry, separators=(",", ":"), default=str) + "\n").encode()
        with self._lock:
            if self._fd < 0:
                raise OSError(f"journal {self.path} is closed")
            view = memoryview(line)
            while view:
                view = view[os.write(self._fd, view) :]
            os.fsync(self._fd)
            self.entries += 1

    def close(self) -> None:
        with self._lock:
            if self._fd >= 0:
                os.close(self._fd)
                self._fd = -1


def read_journal(path: str | os.PathLike) -> list[dict]:
    """Every complete entry; a line cut by a crash (or otherwise unreadable) is skipped."""
    entries = []
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        return []
    for number, line in enumerate(data.splitlines(), 1):
        if not line.strip():
            continue
        try:
            entry = json.loads(line)
        except ValueError:
            log.warning("%s: line %d unreadable (cut by a crash?), skipped", path, number)
            continue
        if isinstance(entry, dict):
            entries.append(entry)
    return entries
