"""The label rules: how keyed labels, undos and corrections become per-frame references.

A label change is (time_ns, mode, source), as recorded on /labels. The operator keys
modes live (source "operator", ...); an undo (source "undo" or "undo:MODE") takes back
the latest change still in force; corrections (source "correction", made offline in
`replay --tui`) are laid over the result. A change holds from its time until the next.

Two references come out of them (inference.evaluation): `locomotion`, the subject's mode
keyed live (undos applied, corrections not), and `terrain`, what each image shows (the
simulator's truth where the recording has it, else the corrected labels when there are
corrections, else none).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import NamedTuple

import numpy as np

from devices.frames import MODES

UNDO = "undo"  # a label whose source is "undo" or "undo:MODE" takes back a change
CORRECTION = "correction"  # labels added in the replay UI (tui.replay), over the originals


class LabelChange(NamedTuple):
    """One change of a mode reference: `mode` from `time_ns` on. The live label book, the
    replay screen's corrections and the reader all speak in these."""

    time_ns: int
    mode: str  # "" for an undo that leaves no mode in force
    source: str  # operator | simulator | undo | undo:MODE | correction


def mode_index(mode: str | None) -> int:
    return MODES.index(mode) if mode in MODES else -1


def is_undo(source: str) -> bool:
    return source == UNDO or source.startswith(UNDO + ":")


def change_from_message(d: dict) -> LabelChange:
    """A decoded /labels message as a change."""
    return LabelChange(int(d["time_ns"]), d.get("mode", "") or "", d.get("source", ""))


def in_time_order(changes: Iterable[LabelChange]) -> list[LabelChange]:
    """Changes sorted by time; same-time changes keep their file order (a stable sort)."""
    return sorted(changes, key=lambda c: c[0])


def effective_changes(changes: list[LabelChange]) -> list[LabelChange]:
    """The label changes that define the reference, in time order: each undo removes the
    latest change still in force before it, as if it never happened (the mode before it
    holds from its time); two undos remove two changes. The undo itself records the mode
    the operator went back to: where that differs from what is left (the undone change was
    the first in the file, e.g. the mode in force at the start), that mode holds from the
    undone change's time. Corrections (source "correction") are laid over the result:
    they apply from their time until the next change."""
    ordered = in_time_order(changes)
    kept: list[LabelChange] = []
    for change in ordered:
        t, mode, source = change
        if source == CORRECTION:
            continue
        if not is_undo(source):
            kept.append(change)
            continue
        if not kept:
            continue  # nothing in this file to take back
        undone = kept.pop()
        before = kept[-1][1] if kept else ""
        if mode and mode != before:
            kept.append((undone[0], mode, source))
    corrections = [c for c in ordered if c[2] == CORRECTION]
    return in_time_order(kept + corrections)


def undone(changes: list[LabelChange]) -> set[int]:
    """Positions (in `changes`, time order) of the changes an undo took back."""
    stack: list[int] = []
    out: set[int] = set()
    for k, (_, _, source) in enumerate(changes):
        if source == CORRECTION:
            continue
        if is_undo(source):
            if stack:
                out.add(stack.pop())
        else:
            stack.append(k)
    return out


def labels_at(times_ns: np.ndarray, changes: list[LabelChange]) -> np.ndarray:
    """The mode index in force at each time: the last change at or before it (-1: none)."""
    out = np.full(len(times_ns), -1, dtype=int)
    if not changes:
        return out
    change_times = np.array([c[0] for c in changes], dtype=np.int64)
    modes = np.array([mode_index(c[1]) for c in changes], dtype=int)
    k = np.searchsorted(change_times, np.asarray(times_ns, dtype=np.int64), side="right") - 1
    ok = k >= 0
    out[ok] = modes[k[ok]]
    return out


def has_corrections(changes: Iterable[LabelChange]) -> bool:
    return any(c[2] == CORRECTION for c in changes)


def live_changes(reference: list[LabelChange]) -> list[LabelChange]:
    """The changes of the `locomotion` reference: the effective changes keyed live."""
    return [c for c in reference if c[2] != CORRECTION]


TERRAIN_SIMULATOR = "simulator"
TERRAIN_OFFLINE = "offline labels"


def terrain_source(has_truth: bool, changes: Iterable[LabelChange]) -> str | None:
    """Where the `terrain` reference comes from: the simulator's per-image truth, the
    labels made offline (corrections) laid over the live keys, or nowhere (None)."""
    if has_truth:
        return TERRAIN_SIMULATOR
    return TERRAIN_OFFLINE if has_corrections(changes) else None
