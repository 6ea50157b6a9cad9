"""A corpus: recordings folders as a set of trials, each trial counted once.

`select(paths)` picks one file per trial and says which files it leaves out and why
(each file's identity and lineage: capture.recording.lineage):
- a copy with corrected labels stands for its source (the newest copy when there are
  several): the corrected labels win;
- a recovered copy stands for its unfinished original; a finished original wins over a
  recovered copy of it;
- a replay is another model's output on the same trial: left out unless replays are asked
  for (`replays=True`: the newest replay of each trial stands for it);
- a recording made with `--overwrite` supersedes the earlier recordings of its trial.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from capture.errors import CaptureError
from capture.recording.lineage import (
    CORRECTED,
    ORIGINAL_KINDS,
    RECOVERED,
    REPLAY,
    Member,
    describe,
)
from capture.recording.reader import open_recording


@dataclass
class Corpus:
    chosen: list[Member]  # one per trial, in path order
    left_out: list[tuple[Path, str]]  # (file, why)
    notes: list[str] = field(default_factory=list)  # things worth saying, not errors

    @property
    def files(self) -> list[Path]:
        return [m.path for m in self.chosen]

    def nothing_left(self, what: str) -> CaptureError:
        """The one-line error when every file was left out: why, for one file; how many and
        the first reason, for more."""
        if len(self.left_out) == 1:
            path, why = self.left_out[0]
            return CaptureError(f"{what}: {path}: {why}")
        if self.left_out:
            path, why = self.left_out[0]
            return CaptureError(
                f"{what}: all {len(self.left_out)} files were left out (first: {path}: {why})"
            )
        return CaptureError(f"{what}: no recordings")

    def report_lines(self) -> list[str]:
        """What a corpus command prints (to stderr) about the files it did not count."""
        lines = []
        if self.left_out:
            lines.append(f"{len(self.chosen)} trial(s); left out {len(self.left_out)} file(s):")
            lines += [f"  {path}: {why}" for path, why in self.left_out]
        lines += self.notes
        return lines


def given_files(
    paths: Iterable[str | os.PathLike],
    wanted: Callable[[Path], bool],
    what: str,
    error: type[Exception] = CaptureError,
) -> list[Path]:
    """The files given, and the `wanted` ones in the given folders (and their subfolders),
    sorted within each folder; a folder without any (`what` names them) or a path that is
    not there is an `error`."""
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(f for f in p.rglob("*") if wanted(f))
            if not found:
                raise error(f"{p}: no {what} in this folder")
            out += found
        elif p.exists():
            out.append(p)
        else:
            raise error(f"{p}: no such file or folder")
    return out


def _is_recording(f: Path) -> bool:
    return f.suffix == ".mcap" and f.is_file() and not f.name.startswith(".")  # in progress


def recording_files(paths: Iterable[str | os.PathLike]) -> list[Path]:
    """The .mcap files given, and those in the given folders (and their subfolders)."""
    return list(dict.fromkeys(given_files(paths, _is_recording, ".mcap recordings")))


def select(
    paths: Iterable[str | os.PathLike],
    *,
    replays: bool = False,
    progress: Callable[[Iterable], Iterable] | None = None,
) -> Corpus:
    """One file per trial from `paths` (files and folders), and what was left out, why."""
    files = recording_files(paths)
    left: list[tuple[Path, str]] = []
    members: list[Member] = []
    for f in progress(files) if progress is not None else files:
        try:
            members.append(describe(open_recording(f)))
        except CaptureError as e:
            left.append((f, f"unreadable: {e}"))
    by_id = {m.id: m for m in members}
    by_name: dict[str, list[Member]] = {}
    for m in members:
        by_name.setdefault(m.path.name, []).append(m)

    def source_of(m: Member) -> Member | None:
        if m.kind in ORIGINAL_KINDS:
            return None
        if m.source_id and m.source_id in by_id:
            return by_id[m.source_id]
        named = by_name.get(m.source_name, [])
        same_folder = [n for n in named if n.path.parent == m.path.parent]
        found = (same_folder or named or [None])[0]
        return found if found is not m else None

    def root_of(m: Member) -> tuple[str, Member | None]:
        seen = {m.id}
        while True:
            s = source_of(m)
            if s is None or s.id in seen:
                break
            seen.add(s.id)
            m = s
        if m.kind in ORIGINAL_KINDS:
            return m.id, m
        return f"missing:{m.source_id or m.source_name}", None  # its source is not here

    groups: dict[str, list[Member]] = {}
    root_ids: dict[int, str] = {}  # member (by object) -> its trial's original id
    for m in members:
        key, root = root_of(m)
        groups.setdefault(key, []).append(m)
        root_ids[id(m)] = key
    chosen: list[Member] = []
    for key, group in groups.items():
        original = by_id.get(key)
        pick, why = _pick(group, original if original in group else None, replays)
        if pick is not None:
            chosen.append(pick)
        left += [
            (m.path, why.get(id(m), "another file of the same trial"))
            for m in group
            if m is not pick
        ]
    superseded = {i: m for m in chosen for i in m.supersedes}
    kept = []
    for m in chosen:
        by = superseded.get(root_ids[id(m)])
        if by is not None and by is not m:
            left.append((m.path, f"superseded by {by.path.name} (recorded again with --overwrite)"))
        else:
            kept.append(m)
    notes = []
    by_trial: dict[tuple, list[Member]] = {}
    for m in kept:
        if m.trial[0] and m.trial[2] is not None:
            by_trial.setdefault(m.trial, []).append(m)
    for same in by_trial.values():
        if len(same) > 1:
            names = ", ".join(m.path.name for m in same)
            notes.append(
                f"note: {same[0].trial_name} has {len(same)} separate recordings ({names}): "
                "each is counted"
            )
    kept.sort(key=lambda m: str(m.path))
    left.sort(key=lambda x: str(x[0]))
    return Corpus(kept, left, notes)


def _newest(members: list[Member]) -> Member:
    return max(members, key=lambda m: (m.mtime, str(m.path)))


def _pick(
    group: list[Member], original: Member | None, replays: bool
) -> tuple[Member | None, dict[int, str]]:
    """The file that stands for one trial, and why each other file of it is left out."""
    why: dict[int, str] = {}  # by member object
    by_kind: dict[str, list[Member]] = {}
    for m in group:
        by_kind.setdefault(m.kind, []).append(m)
    replay_list = by_kind.get(REPLAY, [])
    if replays:
        if not replay_list:
            for m in group:
                why[id(m)] = "no replay of this trial (replays were asked for)"
            return None, why
        pick = _newest(replay_list)
        for m in group:
            why[id(m)] = (
                f"an older replay of the same trial ({pick.path.name} is newer)"
                if m.kind == REPLAY
                else f"replay {pick.path.name} stands for this trial"
            )
        return pick, why
    name = (original.path.name if original is not None else None) or "its source"
    for m in replay_list:
        why[id(m)] = (
            f"replay of {m.source_name or name} ({m.how or 'another model'}): another model's "
            "output on the same trial (--replays takes replays instead)"
        )
    corrected = by_kind.get(CORRECTED, [])
    recovered = by_kind.get(RECOVERED, [])
    if corrected:
        pick = _newest(corrected)
        for m in corrected:
            if m is not pick:
                why[id(m)] = f"an older copy with corrected labels ({pick.path.name} is newer)"
        for m in [*recovered, *([original] if original else [])]:
            why[id(m)] = f"its labels are corrected in {pick.path.name}"
        return pick, why
    if recovered and (original is None or not original.complete):
        pick = _newest(recovered)
        for m in recovered:
            if m is not pick:
                why[id(m)] = f"another recovered copy ({pick.path.name} is newer)"
        if original is not None:
            why[id(original)] = f"unfinished; the recovered copy {pick.path.name} stands for it"
        return pick, why
    for m in recovered:
        why[id(m)] = f"a recovered copy of {name}, which is finished"
    return original, why
