"""The shape of a classifier's errors over time: how often it errs, in runs of what length,
how sure it is when wrong, and where (near a change of terrain, in swing or stance).

What a fusion method must cope with is not the error rate alone: an HMM or a vote removes
errors that come alone and unsure, not runs of confident ones (Zhang et al. 2019: "the
decisions from error images are usually less credible than the stable decisions"). These
pure functions describe one decision sequence against its reference, so that a
classifier's errors can be set beside another's (a real one's scores against the
simulator's, docs/simulator.md), and are pooled over trials by summing.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from inference.evaluation.transitions import pool_records, reference_changes

NEAR_CHANGE_S = 0.5  # an error this close to a change of the reference is a transition's
SURE = 0.9  # a wrong decision this sure or surer is confident
RUN_BINS = ((1, 1), (2, 2), (3, 4), (5, 8), (9, None))  # run lengths, frames
RUN_CAP = 9  # runs this long or longer are counted together (RUN_BINS' last)
CONF_BINS = 1000  # confidences counted in bins of 0.001: a study's figures in fixed memory


def _zeros(n: int):
    return field(default_factory=lambda: np.zeros(n, np.int64))


@dataclass
class ErrorShape:
    """One sequence's error figures, as counts of fixed size whatever its length (so that
    figures pooled over a study of long trials stay small; rates and shares are properties).

    `run_lengths[k]`: runs of k consecutive wrong frames (whatever the wrong mode), k up to
    RUN_CAP (that long or longer); `wrong_confidence` / `right_confidence`: the
    classifier's probability of the mode it chose, counted in CONF_BINS bins, on wrong and
    on right frames; `near_change`: wrong frames within NEAR_CHANGE_S of a change of the
    reference; `swing` / `stance`: (frames, wrong frames) between toe off and heel contact
    and between heel contact and toe off (0, 0 without gait events); `confusions`: wrong
    frames per (reference mode, decision) pair."""

    frames: int
    errors: int
    minutes: float
    run_lengths: np.ndarray = _zeros(RUN_CAP + 1)
    wrong_confidence: np.ndarray = _zeros(CONF_BINS)
    right_confidence: np.ndarray = _zeros(CONF_BINS)
    near_change: int = 0
    swing: tuple[int, int] = (0, 0)
    stance: tuple[int, int] = (0, 0)
    confusions: dict[tuple[int, int], int] = field(default_factory=dict)

    @property
    def error_rate(self) -> float:
        return self.errors / self.frames if self.frames else float("nan")

    @property
    def runs(self) -> int:
        return int(self.run_lengths.sum())

    @property
    def runs_per_min(self) -> float:
        return self.runs / self.minutes if self.minutes > 0 else float("nan")

    @property
    def in_runs(self) -> float:
        """The share of wrong frames in runs of two frames or more."""
        return (
            (self.errors - int(self.run_lengths[1])) / self.errors if self.errors else float("nan")
        )

    def run_histogram(self) -> list[int]:
        """Runs per RUN_BINS bin."""
        return [int(self.run_lengths[lo : (hi or RUN_CAP) + 1].sum()) for lo, hi in RUN_BINS]

    @property
    def confident_wrong(self) -> float:
        """The share of wrong frames decided with probability SURE or more."""
        c = self.wrong_confidence
        return float(c[_bin(SURE) :].sum() / c.sum()) if c.sum() else float("nan")

    @property
    def near_change_share(self) -> float:
        return self.near_change / self.errors if self.errors else float("nan")

    @staticmethod
    def _rate(frames_wrong: tuple[int, int]) -> float:
        n, w = frames_wrong
        return w / n if n else float("nan")

    @property
    def swing_error_rate(self) -> float:
        return self._rate(self.swing)

    @property
    def stance_error_rate(self) -> float:
        return self._rate(self.stance)


def _near(t: np.ndarray, changes: np.ndarray, within_s: float) -> np.ndarray:
    """Frames within `within_s` of a change (`changes` in time order): the nearest change
    either side of each frame, so memory stays that of the frames on trials of hours."""
    if not len(changes):
        return np.zeros(len(t), bool)
    i = np.searchsorted(changes, t)
    after = changes[np.minimum(i, len(changes) - 1)]
    before = changes[np.maximum(i - 1, 0)]
    return np.minimum(np.abs(after - t), np.abs(t - before)) <= within_s


def error_shape(
    decisions: Sequence[int] | np.ndarray,
    reference: Sequence[int] | np.ndarray,
    probabilities: np.ndarray,
    times_s: np.ndarray,
    minutes: float,
    heel_contacts_s: Sequence[float] = (),
    toe_offs_s: Sequence[float] = (),
) -> ErrorShape:
    """The error figures of `decisions` (mode index per frame, -1: undecided) against
    `reference` (-1: none) over frames with both; `probabilities` (N, modes) give each
    decision's confidence (the decided mode's probability); gait events of the
    instrumented leg, when given, split the frames into swing and stance."""
    d = np.asarray(decisions, dtype=int)
    ref = np.asarray(reference, dtype=int)
    t = np.asarray(times_s, dtype=float)
    p = np.asarray(probabilities, dtype=float)
    scored = (d >= 0) & (ref >= 0)
    wrong = scored & (d != ref)
    idx = np.arange(len(d))
    conf = np.where(scored, p[idx, np.clip(d, 0, p.shape[1] - 1)], np.nan)
    runs = _runs(wrong)
    changes = np.array([t[c.frame] for c in reference_changes(ref)])
    near = _near(t, changes, NEAR_CHANGE_S)
    confusions: dict[tuple[int, int], int] = {}
    for a, b in zip(ref[wrong].tolist(), d[wrong].tolist()):
        confusions[(a, b)] = confusions.get((a, b), 0) + 1
    swing, stance = _phases(t, scored, wrong, heel_contacts_s, toe_offs_s)
    return ErrorShape(
        frames=int(scored.sum()),
        errors=int(wrong.sum()),
        minutes=minutes,
        run_lengths=np.bincount(np.minimum(runs, RUN_CAP), minlength=RUN_CAP + 1),
        wrong_confidence=_counts(conf[wrong]),
        right_confidence=_counts(conf[scored & ~wrong]),
        near_change=int((wrong & near).sum()),
        swing=swing,
        stance=stance,
        confusions=confusions,
    )


def _runs(mask: np.ndarray) -> np.ndarray:
    """Lengths of the runs of True in `mask`."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(m))
    return edges[1::2] - edges[::2]


def _bin(confidence):
    """The CONF_BINS bin of a confidence in [0, 1] (1 in the last)."""
    return np.minimum((np.asarray(confidence) * CONF_BINS).astype(np.int64), CONF_BINS - 1)


def _counts(confidences: np.ndarray) -> np.ndarray:
    return np.bincount(_bin(confidences), minlength=CONF_BINS)


def _median(counts: np.ndarray) -> float | None:
    """The median confidence of binned counts (its bin's middle), None without any."""
    n = int(counts.sum())
    if not n:
        return None
    k = int(np.searchsorted(np.cumsum(counts), (n + 1) / 2))
    return (k + 0.5) / CONF_BINS


def _phases(t, scored, wrong, heel_contacts_s, toe_offs_s) -> tuple[tuple[int, int], ...]:
    """(frames, wrong frames) in swing (toe off to heel contact) and in stance (heel
    contact to toe off); frames before the first event or after the last are neither."""
    events = sorted([(float(x), 0) for x in heel_contacts_s] + [(float(x), 1) for x in toe_offs_s])
    if len(events) < 2:
        return (0, 0), (0, 0)
    times = np.array([e[0] for e in events])
    kinds = np.array([e[1] for e in events])
    k = np.searchsorted(times, t, side="right") - 1
    inside = (k >= 0) & (k < len(events) - 1) & scored
    in_swing = inside & (kinds[np.clip(k, 0, len(events) - 1)] == 1)
    in_stance = inside & ~in_swing
    return (
        (int(in_swing.sum()), int((in_swing & wrong).sum())),
        (int(in_stance.sum()), int((in_stance & wrong).sum())),
    )


def pooled(shapes: Sequence[ErrorShape]) -> ErrorShape:
    """Several sequences' figures as one: counts, lists and minutes joined."""
    if not shapes:
        raise ValueError("nothing to pool")
    confusions: dict[tuple[int, int], int] = {}
    for s in shapes:
        for key, n in s.confusions.items():
            confusions[key] = confusions.get(key, 0) + n
    return pool_records(
        ErrorShape,
        shapes,
        swing=tuple(map(sum, zip(*(s.swing for s in shapes)))),
        stance=tuple(map(sum, zip(*(s.stance for s in shapes)))),
        confusions=confusions,
    )


def _finite(x: float) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def summary(shape: ErrorShape) -> dict:
    """The figures as JSON: rates and shares as fractions, null where undefined."""
    return {
        "frames": shape.frames,
        "errors": shape.errors,
        "error_rate": _finite(shape.error_rate),
        "runs": shape.runs,
        "runs_per_min": _finite(shape.runs_per_min),
        "in_runs": _finite(shape.in_runs),
        "run_lengths": {
            (f"{lo}" if hi == lo else f"{lo}+" if hi is None else f"{lo}-{hi}"): n
            for (lo, hi), n in zip(RUN_BINS, shape.run_histogram())
        },
        "confidence_wrong_median": _median(shape.wrong_confidence),
        "confidence_right_median": _median(shape.right_confidence),
        "confident_wrong": _finite(shape.confident_wrong),
        "near_change": _finite(shape.near_change_share),
        "error_rate_swing": _finite(shape.swing_error_rate),
        "error_rate_stance": _finite(shape.stance_error_rate),
    }
