"""The journal: labels and operator markers appended beside the recording, on disk at once.

The MCAP file reaches the disk a chunk at a time (about once a second); the operator's
labels must survive anything, so each one is also appended as a line of JSON to
`<recording>.journal.jsonl` and fsync'ed before the call returns. `walkcap recover` merges
the journal back into the recording.

The file is JSON Lines: one object a line, read by `json.loads`, `jq` or pandas'
`read_json(lines=True)` as it is. Each object carries its own check: the key `crc32`, the
CRC-32 (eight hex digits) of the object's other keys canonically encoded (sorted keys,
compact separators, ASCII), so that a reader recomputes it from the parsed object without
the line's bytes. A line whose CRC fails (a bad disk, a bad copy), that a crash cut, or
whose values cannot be (a time that is no integer, a label without a mode) is skipped and
reported by its line number, never guessed. Two older line forms are read too: the JSON, a
tab and the CRC-32 of the JSON's bytes; and bare JSON without a check. In a journal where
any line has a check, a line without one is damage.
"""

from __future__ import annotations

import json
import logging
import os
import re
import threading
import zlib
from dataclasses import dataclass, field
from pathlib import Path

log = logging.getLogger(__name__)

SUFFIX = ".journal.jsonl"
CRC_KEY = "crc32"
_TABBED = re.compile(rb"(.*)\t([0-9a-f]{8})", re.DOTALL)  # the older form: JSON, tab, CRC
_HEX8 = re.compile(r"[0-9a-f]{8}")
_TIME_MAX = 2**63 - 1


def canonical(entry: dict) -> bytes:
    """The one encoding the check is computed over: sorted keys, compact, ASCII."""
    return json.dumps(entry, sort_keys=True, separators=(",", ":"), ensure_ascii=True).encode()


def entry_crc(entry: dict) -> str:
    """The CRC-32 of an entry's keys other than the check itself, as eight hex digits."""
    return f"{zlib.crc32(canonical({k: v for k, v in entry.items() if k != CRC_KEY})):08x}"


def encode_line(entry: dict) -> bytes:
    """One journal line: the entry's JSON object with its `crc32` key, and a newline."""
    # through JSON once, so the check covers exactly what a reader parses back (str() of
    # a value JSON cannot hold, lists for tuples)
    plain = json.loads(json.dumps(entry, default=str))
    crc = entry_crc(plain)
    plain.pop(CRC_KEY, None)
    return canonical(plain)[:-1] + f',"{CRC_KEY}":"{crc}"}}\n'.encode()


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
        line = encode_line(entry)
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


@dataclass
class JournalRead:
    """The entries of a journal that can be believed, and the lines that cannot."""

    entries: list[dict] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)  # "line N: why", in line order


def _problem(entry) -> str:
    """Why an entry cannot be what it says ("" when it can)."""
    if not isinstance(entry, dict):
        return "not an object"
    kind = entry.get("type")
    if kind not in ("label", "event", "start", "end", "failed"):
        return f"unknown type {kind!r}"
    t = entry.get("time_ns")
    if kind in ("label", "event") or "time_ns" in entry:
        if isinstance(t, bool) or not isinstance(t, int) or not 0 <= t <= _TIME_MAX:
            return f"time_ns {t!r} is no time"
    if kind == "label":
        for key in ("mode", "source"):
            if not isinstance(entry.get(key), str):
                return f"{key} {entry.get(key)!r} is not text"
    if kind == "event":
        for key in ("device", "kind", "message"):
            if key in entry and not isinstance(entry[key], str):
                return f"{key} {entry[key]!r} is not text"
        if not isinstance(entry.get("details", {}), dict):
            return "details is not an object"
    return ""


def _parse(line: bytes) -> tuple[object, bool, str]:
    """(the entry, whether the line carries a check, why it cannot be believed or "")."""
    tabbed = _TABBED.fullmatch(line)
    if tabbed:
        text, crc = tabbed.groups()
        if zlib.crc32(text) != int(crc, 16):
            return None, True, "CRC mismatch"
        line = text
    try:
        entry = json.loads(line)
    except ValueError:
        return None, bool(tabbed), "unreadable"
    if tabbed or not isinstance(entry, dict) or CRC_KEY not in entry:
        return entry, bool(tabbed), ""
    crc = entry.pop(CRC_KEY)
    if not isinstance(crc, str) or not _HEX8.fullmatch(crc) or crc != entry_crc(entry):
        return None, True, "CRC mismatch"
    return entry, True, ""


def check_journal(path: str | os.PathLike) -> JournalRead:
    """Every entry whose line proves itself; the others listed by line number."""
    out = JournalRead()
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        return out
    lines = data.split(b"\n")
    cut = lines.pop() if lines else b""  # after the last newline: empty, or cut by a crash
    parsed = [_parse(line) for line in lines]
    checked = any(has_check for _, has_check, _ in parsed)
    for number, (line, (entry, has_check, why)) in enumerate(zip(lines, parsed), 1):
        if not line.strip():
            continue
        if not why and not has_check and checked:
            why = "no CRC (damaged)"
        if not why:
            why = _problem(entry)
        if why:
            out.skipped.append(f"line {number}: {why}")
            continue
        out.entries.append(entry)
    if cut.strip():
        out.skipped.append(f"line {len(lines) + 1}: cut off (a crash while it was written)")
    return out


def read_journal(path: str | os.PathLike) -> list[dict]:
    """Every entry that can be believed (check_journal); the others are logged."""
    result = check_journal(path)
    for why in result.skipped:
        log.warning("%s: %s, skipped", path, why)
    return result.entries
