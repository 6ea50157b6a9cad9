"""Transition metrics: what a prosthesis controller feels of a decision sequence.

A controller acts on mode *switches*, so frame accuracy alone hides what matters: a decision
that flips for one frame while the terrain stays the same puts the leg in the wrong mode.
These pure functions compare the switches of a decision sequence with the changes of a
reference sequence (mode indices per frame, -1 where there is none):

- reference changes (`reference_changes`): every change of the reference. The `terrain`
  reference is what each image shows, and near a transition it flips back and forth as
  the swinging thigh glances at the other terrain. A change is *settled*
  (`settled_changes`) when the new mode then holds for at least `min_dwell_s`: a terrain
  the walker moves onto lasts at least one step (0.5 s at 120 steps a minute); a shorter
  run is a glance.
- decision switches (`decision_switches`): every frame whose decision differs from the
  last decided frame's (undecided frames, -1, are skipped).
- matching (`match_switches`): each settled change, in time order, takes the nearest
  unmatched switch *to the new mode* whose decision is known between `before_s` before and
  `after_s` after the change; then each glance takes one the same way. A settled change
  with no switch is missed; a switch matched to no change, settled or glance, is spurious
  (the reference did not change to that mode nearby). Following a glance is neither
  spurious nor needed. At 15 fps this is the count of per-image labels that matches each
  label change to the nearest decision change to the new mode within 30 frames and calls
  every other decision change spurious, with glances not counted as missed.
- timing: a frame's decision is known `delay_frames` frames later (the method's delay), so
  the switch time is the time of frame k + delay. `delay` is that time minus the reference
  change's time (positive: after it). Against the `terrain` reference it is the switch
  delay; against the `locomotion` reference (the subject's mode keyed live) its negative is
  the lead time: how long before the subject's mode changed the decision switched.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

PAPER_FPS = 15.0  # the paper's camera rate: frame times when a sequence has none

# Walking: a step takes 0.5-0.6 s at 100-120 steps a minute; the terrain ahead is seen up to
# 2.5 m ([preprocess] max_forward_m), about 2 s at 1.2 m/s.
MIN_DWELL_S = 0.5
TERRAIN_WINDOW_S = (2.0, 2.0)  # (before, after) a terrain change
LOCOMOTION_WINDOW_S = (3.0, 2.0)  # a switch leads the subject's step by up to ~2 s


@dataclass(frozen=True)
class Change:
    """A mode change at `frame` (the first frame of the new mode)."""

    frame: int
    before: int
    after: int


@dataclass
class TransitionStats:
    """The switches of one decision sequence against one reference.

    `delays_s` / `delays_frames`: per matched reference change, the switch's known time
    minus the change's time (positive: after it), in reference-change order.
    """

    reference: str
    changes: int  # settled reference changes
    switches: int  # decision switches
    matched: int
    missed: int
    spurious: int
    minutes: float  # the sequence's duration
    delays_s: list[float] = field(default_factory=list)
    delays_frames: list[int] = field(default_factory=list)

    @property
    def spurious_per_min(self) -> float:
        return self.spurious / self.minutes if self.minutes > 0 else math.nan

    @property
    def lead_times_s(self) -> list[float]:
        return [-d for d in self.delays_s]

    @property
    def late(self) -> int:
        """Matched changes switched after the reference changed (negative lead time)."""
        return sum(1 for d in self.delays_s if d > 0)


def frame_times(n: int, times_s: np.ndarray | None = None, fps: float = PAPER_FPS) -> np.ndarray:
    """Frame times in seconds: the given ones, else frames at `fps`."""
    if times_s is not None and len(times_s) == n:
        return np.asarray(times_s, dtype=float)
    return np.arange(n, dtype=float) / fps


def duration_minutes(times_s: np.ndarray) -> float:
    """A sequence's duration: first to last frame plus one frame period."""
    t = np.asarray(times_s, dtype=float)
    if len(t) == 0:
        return 0.0
    period = float(np.median(np.diff(t))) if len(t) > 1 else 1.0 / PAPER_FPS
    return (float(t[-1] - t[0]) + period) / 60.0


def settled_changes(
    reference: Sequence[int] | np.ndarray, times_s: np.ndarray, min_dwell_s: float = MIN_DWELL_S
) -> list[Change]:
    """The reference's changes to a mode that then holds for at least `min_dwell_s`.

    Runs shorter than that (or without a reference, -1) do not change the settled mode: a
    glance at the next terrain and back is no change; the change is placed at the start of
    the run that settles. The run that reaches the end of the sequence counts whatever its
    length (the sequence ends, not the mode)."""
    ref = np.asarray(reference, dtype=int)
    t = np.asarray(times_s, dtype=float)
    n = len(ref)
    if n == 0:
        return []
    starts = np.flatnonzero(np.r_[True, ref[1:] != ref[:-1]])
    ends = np.r_[starts[1:], n]
    period = float(np.median(np.diff(t))) if n > 1 else 0.0
    settled = -1
    out: list[Change] = []
    for s, e in zip(starts.tolist(), ends.tolist()):
        mode = int(ref[s])
        if mode < 0:
            continue
        held = float(t[e - 1] - t[s]) + period
        if held + 1e-9 < min_dwell_s and e < n:
            continue
        if settled >= 0 and mode != settled:
            out.append(Change(s, settled, mode))
        settled = mode
    return out


def reference_changes(reference: Sequence[int] | np.ndarray) -> list[Change]:
    """Every change of the reference mode (frames without one, -1, skipped)."""
    return decision_switches(reference)


def decision_switches(decisions: Sequence[int] | np.ndarray) -> list[Change]:
    """Every change of the decided mode (undecided frames, -1, skipped)."""
    d = np.asarray(decisions, dtype=int)
    out: list[Change] = []
    last = -1
    for k in np.flatnonzero(d >= 0).tolist():
        mode = int(d[k])
        if last >= 0 and mode != last:
            out.append(Change(k, last, mode))
        last = mode
    return out


def match_switches(
    changes: Sequence[Change],
    switches: Sequence[Change],
    times_s: np.ndarray,
    delay_frames: int = 0,
    window_s: tuple[float, float] = TERRAIN_WINDOW_S,
    used: set[int] | None = None,
) -> list[tuple[Change, Change | None]]:
    """Each reference change with its switch (None: none), in change order; see the
    module docstring. A switch is known at the time of frame k + delay_frames. `used`:
    indices of switches already matched (updated)."""
    t = np.asarray(times_s, dtype=float)
    n = len(t)
    before, after = window_s
    used = set() if used is None else used
    pairs: list[tuple[Change, Change | None]] = []
    for c in changes:
        t_change = t[c.frame]
        best, best_gap = None, math.inf
        for i, s in enumerate(switches):
            if i in used or s.after != c.after:
                continue
            gap = _known_time(t, n, s.frame, delay_frames) - t_change
            if -before - 1e-9 <= gap <= after + 1e-9 and abs(gap) < abs(best_gap):
                best, best_gap = i, gap
        if best is None:
            pairs.append((c, None))
        else:
            used.add(best)
            pairs.append((c, switches[best]))
    return pairs


def _known_time(t: np.ndarray, n: int, frame: int, delay_frames: int) -> float:
    """When frame's decision is known: frame + delay's time, extrapolated past the end."""
    k = frame + delay_frames
    if k < n:
        return float(t[k])
    period = float(np.median(np.diff(t))) if n > 1 else 1.0 / PAPER_FPS
    return float(t[-1]) + (k - n + 1) * period


def transition_stats(
    decisions: Sequence[int] | np.ndarray,
    reference: Sequence[int] | np.ndarray,
    times_s: np.ndarray | None = None,
    *,
    name: str = "terrain",
    delay_frames: int = 0,
    fps: float = PAPER_FPS,
    min_dwell_s: float = MIN_DWELL_S,
    window_s: tuple[float, float] | None = None,
) -> TransitionStats:
    """Switches of `decisions` against `reference` (see the module docstring). The window
    defaults to TERRAIN_WINDOW_S, or LOCOMOTION_WINDOW_S for name "locomotion"."""
    d = np.asarray(decisions, dtype=int)
    t = frame_times(len(d), times_s, fps)
    if window_s is None:
        window_s = LOCOMOTION_WINDOW_S if name == "locomotion" else TERRAIN_WINDOW_S
    changes = settled_changes(reference, t, min_dwell_s)
    settled_frames = {c.frame for c in changes}
    glances = [c for c in reference_changes(reference) if c.frame not in settled_frames]
    switches = decision_switches(d)
    used: set[int] = set()
    pairs = match_switches(changes, switches, t, delay_frames, window_s, used)
    match_switches(glances, switches, t, delay_frames, window_s, used)
    matched = [(c, s) for c, s in pairs if s is not None]
    n = len(t)
    return TransitionStats(
        reference=name,
        changes=len(changes),
        switches=len(switches),
        matched=len(matched),
        missed=len(pairs) - len(matched),
        spurious=len(switches) - len(used),
        minutes=duration_minutes(t),
        delays_s=[_known_time(t, n, s.frame, delay_frames) - float(t[c.frame]) for c, s in matched],
        delays_frames=[s.frame + delay_frames - c.frame for c, s in matched],
    )


def pooled(stats: Sequence[TransitionStats]) -> TransitionStats:
    """Several sequences' stats as one: counts and minutes summed, delays concatenated."""
    if not stats:
        raise ValueError("nothing to pool")
    return pool_records(TransitionStats, stats, reference=stats[0].reference)


def pool_records(cls, stats: Sequence, **given):
    """One record of dataclass `cls` for several: its number fields summed, its list fields
    concatenated in order; `given` sets the others (e.g. what the records are against)."""
    values = {}
    for f in dataclasses.fields(cls):
        if f.name in given:
            continue
        first = getattr(stats[0], f.name)
        if isinstance(first, list):
            values[f.name] = [x for s in stats for x in getattr(s, f.name)]
        else:
            values[f.name] = sum(getattr(s, f.name) for s in stats)
    return cls(**values, **given)


def _finite(x: float) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def summary(stats: TransitionStats) -> dict:
    """The figures eval reports, JSON-ready (None where undefined). Against `terrain`: the
    switch delay; against `locomotion`: the lead time (median, 10th percentile, how many
    matched changes were switched after the subject's mode changed)."""
    out: dict = {
        "reference": stats.reference,
        "changes": stats.changes,
        "switches": stats.switches,
        "missed": stats.missed,
        "spurious": stats.spurious,
        "minutes": _finite(stats.minutes),
        "spurious_per_min": _finite(stats.spurious_per_min),
    }
    delays = np.asarray(stats.delays_s, dtype=float)
    if stats.reference == "locomotion":
        lead = -delays
        out["lead_ms"] = {
            "median": _finite(1e3 * float(np.median(lead))) if lead.size else None,
            "p10": _finite(1e3 * float(np.percentile(lead, 10))) if lead.size else None,
        }
        out["late"] = stats.late
    else:
        frames = np.asarray(stats.delays_frames, dtype=float)
        out["delay_frames"] = {
            "median": _finite(float(np.median(frames))) if frames.size else None,
            "mean": _finite(float(frames.mean())) if frames.size else None,
        }
        out["delay_ms"] = {
            "median": _finite(1e3 * float(np.median(delays))) if delays.size else None,
            "mean": _finite(1e3 * float(delays.mean())) if delays.size else None,
        }
    return out
