"""Per-step metrics: a decision sequence judged where a prosthesis acts on it, at gait events.

A powered prosthesis reads the mode at heel contact (for the stance that follows) and at
toe off (for the swing). These pure functions take a trial's frame times, a method's final
decisions and its delay, and the instrumented leg's gait events with each step's mode
(`Steps`), and count (docs/analysis.md, "Per-step metrics"):

- the decision *in force* at a time t: the newest decision known at t, i.e. the decision
  of frame k - delay where k is the last frame at or before t (the decision of a frame is
  known `delay_frames` frames later); none before the first one is known;
- step i runs from heel contact i to heel contact i+1 and has the mode `modes[i]` (the
  terrain under the foot at that heel contact; -1: unknown, not scored);
- an error at heel contact i: the decision in force there is not `modes[i]`;
- an error at toe off: the decision in force at a toe off is not the mode of the step whose
  heel contact ends that swing (the foot swings onto that terrain); a toe off with no heel
  contact after it is not scored;
- a transition step: a step whose mode differs from the step before's (both known);
  late when the decision at its heel contact is wrong;
- lead steps of a transition step: how many heel contacts before it the decision in force
  already held the new mode, without interruption up to the transition step (0: it
  switched during the step before); negative when late (-k: first right k heel contacts
  after it; None: not right before the next transition step or the end);
- a critical error: an error at a heel contact more than one step from every transition
  step (|i - j| > 1 for every transition step j), i.e. in steady walking, where a wrong mode
  disturbs the stance (Zhang, Liu and Huang 2015).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from inference.evaluation.transitions import pool_records

HEEL_CONTACT = "heel_contact"
TOE_OFF = "toe_off"


@dataclass
class Steps:
    """A trial's gait events on its frame clock (seconds, as Trial.times_s).

    `modes`: per heel contact, the mode index of its step (-1: unknown); `source`: whose
    events ("simulator": the simulated walker's truth; "imu": the detector's, "scores": a
    score file's column); `mode_source`: where the modes come from ("simulator" or
    "locomotion", the subject's mode keyed live at the heel contact)."""

    heel_contacts_s: np.ndarray
    modes: np.ndarray
    toe_offs_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    source: str = "simulator"
    mode_source: str = "simulator"

    def __post_init__(self) -> None:
        self.heel_contacts_s = np.asarray(self.heel_contacts_s, dtype=float)
        self.modes = np.asarray(self.modes, dtype=int)
        self.toe_offs_s = np.asarray(self.toe_offs_s, dtype=float)
        if self.modes.shape != self.heel_contacts_s.shape:
            raise ValueError("one mode per heel contact")
        order = np.argsort(self.heel_contacts_s, kind="stable")
        self.heel_contacts_s, self.modes = self.heel_contacts_s[order], self.modes[order]
        self.toe_offs_s = np.sort(self.toe_offs_s)


@dataclass
class StepStats:
    """One decision sequence's per-step figures (counts; rates are properties)."""

    heel_contacts: int  # heel contacts scored (a known mode, a decision in force)
    errors_at_heel_contact: int
    toe_offs: int  # toe offs scored
    errors_at_toe_off: int
    transition_steps: int
    transition_steps_late: int
    critical_errors: int
    minutes: float
    lead_steps: list[int | None] = field(default_factory=list)  # per transition step
    source: str = "simulator"
    mode_source: str = "simulator"

    @property
    def error_rate_at_heel_contact(self) -> float:
        return self.errors_at_heel_contact / self.heel_contacts if self.heel_contacts else math.nan

    @property
    def error_rate_at_toe_off(self) -> float:
        return self.errors_at_toe_off / self.toe_offs if self.toe_offs else math.nan

    @property
    def critical_per_min(self) -> float:
        return self.critical_errors / self.minutes if self.minutes > 0 else math.nan


def decisions_in_force(
    frame_times_s: np.ndarray, final: np.ndarray, delay_frames: int, at_s: np.ndarray
) -> np.ndarray:
    """The decision in force at each time of `at_s` (see the module docstring); -1 where
    no decision is known yet, or the frame's decision is -1."""
    t = np.asarray(frame_times_s, dtype=float)
    d = np.asarray(final, dtype=int)
    k = np.searchsorted(t, np.asarray(at_s, dtype=float), side="right") - 1 - int(delay_frames)
    out = np.full(len(k), -1)
    ok = k >= 0
    out[ok] = d[np.minimum(k[ok], len(d) - 1)]
    return out


def step_stats(
    frame_times_s: np.ndarray,
    final: np.ndarray,
    delay_frames: int,
    steps: Steps,
    minutes: float | None = None,
) -> StepStats:
    """The per-step figures of `final` (one decision a frame) at `steps`' gait events."""
    t = np.asarray(frame_times_s, dtype=float)
    if not len(t):  # nothing decided: nothing scored
        return StepStats(0, 0, 0, 0, 0, 0, 0, 0.0, [], steps.source, steps.mode_source)
    if minutes is None:
        period = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
        minutes = (float(t[-1] - t[0]) + period) / 60.0
    # events outside the frames are outside what the method decided
    inside = (steps.heel_contacts_s >= t[0]) & (steps.heel_contacts_s <= t[-1])
    hc, modes = steps.heel_contacts_s[inside], steps.modes[inside]
    at_hc = decisions_in_force(t, final, delay_frames, hc)
    scored = (modes >= 0) & (at_hc >= 0)
    wrong = scored & (at_hc != modes)

    transitions = [
        i
        for i in range(1, len(modes))
        if modes[i] >= 0 and modes[i - 1] >= 0 and modes[i] != modes[i - 1]
    ]
    near = np.zeros(len(modes), dtype=bool)
    for j in transitions:
        near[max(0, j - 1) : j + 2] = True
    late = sum(1 for j in transitions if at_hc[j] != modes[j])
    lead = [_lead(at_hc, modes, j, transitions) for j in transitions]

    # toe offs: the swing lands at the next heel contact, whose step's mode it needs
    to = steps.toe_offs_s
    to = to[(to >= t[0]) & (to <= t[-1])]
    nxt = np.searchsorted(hc, to, side="right")  # the heel contact after each toe off
    has_next = nxt < len(hc)
    to, nxt = to[has_next], nxt[has_next]
    need = modes[nxt]
    at_to = decisions_in_force(t, final, delay_frames, to)
    to_scored = (need >= 0) & (at_to >= 0)
    return StepStats(
        heel_contacts=int(scored.sum()),
        errors_at_heel_contact=int(wrong.sum()),
        toe_offs=int(to_scored.sum()),
        errors_at_toe_off=int((to_scored & (at_to != need)).sum()),
        transition_steps=len(transitions),
        transition_steps_late=late,
        critical_errors=int((wrong & ~near).sum()),
        minutes=float(minutes),
        lead_steps=lead,
        source=steps.source,
        mode_source=steps.mode_source,
    )


def _lead(at_hc: np.ndarray, modes: np.ndarray, j: int, transitions: Sequence[int]) -> int | None:
    """Lead steps of transition step j (module docstring)."""
    new = modes[j]
    previous = max((i for i in transitions if i < j), default=0)
    following = min((i for i in transitions if i > j), default=len(modes))
    if at_hc[j] == new:
        k = 0
        while j - k - 1 >= previous and at_hc[j - k - 1] == new:
            k += 1
        return k
    for i in range(j + 1, following):
        if at_hc[i] == new:
            return -(i - j)
    return None


def pooled(stats: Sequence[StepStats]) -> StepStats:
    """Several sequences' figures as one: counts and minutes summed, leads concatenated."""
    if not stats:
        raise ValueError("nothing to pool")
    return pool_records(
        StepStats,
        stats,
        source="+".join(sorted({s.source for s in stats})),
        mode_source="+".join(sorted({s.mode_source for s in stats})),
    )


def _finite(x: float) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def summary(stats: StepStats) -> dict:
    """The figures `eval --json` reports under `steps.<method>`, JSON-ready."""
    leads = [x for x in stats.lead_steps if x is not None]
    return {
        "source": stats.source,
        "mode_source": stats.mode_source,
        "heel_contacts": stats.heel_contacts,
        "errors_at_heel_contact": stats.errors_at_heel_contact,
        "error_rate_at_heel_contact": _finite(stats.error_rate_at_heel_contact),
        "toe_offs": stats.toe_offs,
        "errors_at_toe_off": stats.errors_at_toe_off,
        "error_rate_at_toe_off": _finite(stats.error_rate_at_toe_off),
        "transition_steps": stats.transition_steps,
        "transition_steps_late": stats.transition_steps_late,
        "lead_steps": {
            "values": list(stats.lead_steps),
            "median": _finite(float(np.median(leads))) if leads else None,
        },
        "critical_errors": stats.critical_errors,
        "critical_per_min": _finite(stats.critical_per_min),
    }
