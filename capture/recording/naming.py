"""Trial numbers: the file names walkcap gives recordings (SUBJECT_CONDITION_tNN_...), the
next free trial, and what to do when a new recording's trial has files already."""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from pathlib import Path

from capture.errors import CaptureError
from capture.recording.lineage import RECORDING, describe
from capture.recording.reader import open_recording


def trial_files(folder: str | os.PathLike, subject: str, condition: str) -> dict[int, list[Path]]:
    """The trial numbers of `subject` and `condition` that have files in `folder`, from the
    file names walkcap gives recordings (SUBJECT_CONDITION_tNN_...)."""
    pattern = re.compile(rf"^{re.escape(subject)}_{re.escape(condition)}_t(\d+)[_.]")
    out: dict[int, list[Path]] = {}
    folder = Path(folder)
    if not folder.is_dir():
        return out
    for f in sorted(folder.glob("*.mcap")):
        m = pattern.match(f.name)
        if m and not f.name.startswith("."):
            out.setdefault(int(m.group(1)), []).append(f)
    return out


def next_free_trial(taken: Iterable[int], start: int = 1) -> int:
    taken = set(taken)
    n = max(1, start)
    while n in taken:
        n += 1
    return n


# What to do when a new recording's trial has files already (Session.start_recording).
NEXT_TRIAL, TRIAL_ERROR, OVERWRITE = "next", "error", "overwrite"


def trial_conflict(
    folder: str | os.PathLike, subject: str, condition: str, trial: int, existing: str
) -> tuple[int, list[str], str]:
    """(trial number to record, ids it supersedes, what to tell the operator) for a new
    recording of `trial`; CaptureError when it exists and `existing` is TRIAL_ERROR."""
    files = trial_files(folder, subject, condition)
    same = files.get(trial)
    if not same:
        return trial, [], ""
    names = ", ".join(f.name for f in same)
    free = next_free_trial(files, trial)
    if existing == NEXT_TRIAL:
        return (
            free,
            [],
            f"{subject} {condition} trial {trial} exists ({names}): recording trial {free}",
        )
    if existing == OVERWRITE:
        ids = []
        for f in same:
            try:
                member = describe(open_recording(f))
            except CaptureError:
                continue
            if member.kind == RECORDING:
                ids.append(member.id)
        return (
            trial,
            ids,
            f"recording {subject} {condition} trial {trial} again: the new file supersedes "
            f"{names} (kept on disk, left out of corpora)",
        )
    raise CaptureError(
        f"{subject} {condition} trial {trial} exists in {Path(folder)} ({names}); "
        f"--overwrite records it again (the earlier file stays on disk, left out of "
        f"corpora), or leave --trial out for the next free number ({free})"
    )
