"""Evaluating classifiers and fusion the way the paper does: per-frame accuracy per trial,
mean +- SD across trials, paired t-tests, accuracy against delay, confusion matrices.

Decisions always come from the streaming objects of `inference.fusion`, pushed frame by
frame and flushed at the end (`run_offline`): offline results are the live ones.
Accuracy is the fraction of frames whose final decision equals the reference, over the
frames that have a reference (-1 = none); the mean over trials is the mean of the trials'
accuracies, as in the paper (not pooled over frames); SD uses n-1.

Two references: `terrain`, what each image shows (the paper's: labelled offline from the
images, or the simulator's per-image truth), and `locomotion`, the subject's mode keyed live,
which changes about a second after the terrain ahead does. Accuracy is scored against the
trial's `reference` (named by `reference_name`, `terrain` unless asked otherwise); the
transition metrics (`inference.transitions`: spurious switches a minute, missed
transitions, switch delay, lead time) against each reference the trial has.

Inputs: score files (CSV, `read_scores`) or recordings (capture.recording.reader.read_trials turns
each into a Trial with `trial_from_recording`), both as `Trial`s.
"""

from __future__ import annotations

import csv
import logging
import math
import re
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from devices.frames import MODE_COLORS, MODES
from inference import transitions as tr
from inference.errors import InferenceError
from inference.fusion import FixedLagSmoother, Fusion, HmmFusion, Voter, make_fusion
from inference.fusion_design import (
    HYSTERESIS,
    N_MODES,
    PAPER_TRANSITION,
    STEADY_EVIDENCE,
    STEADY_STAY,
    estimate_transition,
    mode_indices,
)

log = logging.getLogger(__name__)

PAPER_METHODS = ("cnn", "cnn+voting", "hmm", "hmm+voting")
TITLES = {
    "cnn": "CNN",
    "cnn+voting": "CNN + voting",
    "hmm": "HMM",
    "hmm+voting": "HMM + voting",
    "forward": "forward filter",
    "fixed-lag": "fixed-lag smoother",
    "steady": "steady",
    "steady+gait": "steady + gait",
    "steady+hysteresis": "steady + hysteresis",
}
SCORE_HEADER = (*MODES, "label")  # label: the terrain each image shows
SCORE_HEADER_LOCOMOTION = (*SCORE_HEADER, "locomotion")  # + the mode keyed live
SUM_TOLERANCE = 0.01  # score rows must sum to 1 within this (they are often rounded)


class ScoreFileError(InferenceError):
    """A score CSV is malformed; the message names the file and line."""


@dataclass(frozen=True)
class FusionParameters:
    window: int = 5  # l_w
    vote_delay: int = 1  # l_v
    transition: np.ndarray = field(default_factory=lambda: PAPER_TRANSITION.copy())
    lag: int = 1  # fixed-lag smoother only
    stay: float = STEADY_STAY  # "steady" only
    evidence: float = STEADY_EVIDENCE  # "steady" only
    hysteresis: float = HYSTERESIS  # "steady+hysteresis" only

    def make(self, method: str) -> Fusion:
        return make_fusion(
            method,
            self.window,
            self.vote_delay,
            self.transition,
            self.lag,
            self.stay,
            self.evidence,
            self.hysteresis,
        )

    def delay_frames(self, method: str) -> int:
        return self.make(method).delay_frames


@dataclass
class Trial:
    """One sequence to evaluate: CNN probabilities per frame and the true mode per frame."""

    path: str
    probabilities: np.ndarray  # (N, 5), index order MODES
    reference: Any  # (N,) mode names or indices; None / "" / -1: no reference
    metadata: dict = field(default_factory=dict)  # "subject", "condition", ...
    times_s: np.ndarray | None = None  # (N,) seconds since the first frame; None: unknown
    reference_name: str = "terrain"  # what `reference` is: "terrain" or "locomotion"
    locomotion: Any = None  # (N,) the subject's mode keyed live, when `reference` is terrain
    elevation_deg: np.ndarray | None = None  # (N,) camera above the horizon: gait cues

    def __post_init__(self) -> None:
        self.probabilities = np.asarray(self.probabilities, dtype=float)
        if self.times_s is not None:
            self.times_s = np.asarray(self.times_s, dtype=float)
        if self.probabilities.ndim != 2 or self.probabilities.shape[1] != N_MODES:
            raise InferenceError(
                f"{self.path}: expected probabilities of shape (N, 5), "
                f"got {self.probabilities.shape}"
            )
        try:
            self.reference = mode_indices(self.reference)
        except InferenceError as e:
            raise InferenceError(f"{self.path}: {e}") from None
        if len(self.reference) != len(self.probabilities):
            raise InferenceError(
                f"{self.path}: {len(self.probabilities)} frames but "
                f"{len(self.reference)} reference labels"
            )
        if self.locomotion is not None:
            self.locomotion = mode_indices(self.locomotion)
            if len(self.locomotion) != len(self.probabilities):
                raise InferenceError(
                    f"{self.path}: {len(self.probabilities)} frames but "
                    f"{len(self.locomotion)} locomotion labels"
                )
            if not (self.locomotion >= 0).any():
                self.locomotion = None
        if self.elevation_deg is not None:
            self.elevation_deg = np.asarray(self.elevation_deg, dtype=float)
            if len(self.elevation_deg) != len(self.probabilities):
                raise InferenceError(
                    f"{self.path}: {len(self.probabilities)} frames but "
                    f"{len(self.elevation_deg)} camera elevations"
                )

    def references(self) -> dict[str, np.ndarray]:
        """Every reference the trial has, by name (the scored one first)."""
        out = {self.reference_name: self.reference}
        if self.locomotion is not None and self.reference_name != "locomotion":
            out["locomotion"] = self.locomotion
        return out

    @property
    def subject(self) -> str:
        return str(self.metadata.get("subject") or Path(self.path).stem)

    @property
    def condition(self) -> str:
        return str(self.metadata.get("condition") or "")

    @property
    def title(self) -> str:
        """The trial as a reader names it: subject, condition, trial number."""
        subject, trial = self.metadata.get("subject"), self.metadata.get("trial")
        if not subject:
            return Path(self.path).stem
        parts = [f"subject {subject}"]
        if self.condition:
            parts.append(self.condition)
        if trial not in (None, ""):
            parts.append(f"trial {trial}")
        return ", ".join(parts)


@dataclass
class FusionRun:
    """One method over one sequence; -1 / NaN where a frame got nothing."""

    method: str
    decisions: np.ndarray  # (N,) first stage: argmax, smooth state, filter, smoother
    final: np.ndarray  # (N,) the method's decision (the vote for methods with voting)
    posteriors: np.ndarray  # (N, 5) per frame; NaN where none (HMM: frame 0)


@dataclass
class TrialResult:
    trial: Trial
    accuracy: dict[str, float]
    runs: dict[str, FusionRun]
    # method -> reference name -> its switches against that reference
    transitions: dict[str, dict[str, tr.TransitionStats]] = field(default_factory=dict)


@dataclass
class PairedTest:
    a: str
    b: str
    n: int
    t: float  # NaN when undefined (fewer than 2 trials, identical results)
    p: float


@dataclass
class DelaySweep:
    """Accuracy and spurious switches per trial against the number of delayed frames (NaN:
    not reachable). Spurious switches are counted against the trials' scored reference."""

    delays: list[int]
    accuracy: dict[str, np.ndarray]  # method -> (trials, delays)
    spurious: dict[str, np.ndarray] = field(default_factory=dict)  # method -> (trials, delays)
    minutes: np.ndarray | None = None  # (trials,) each trial's duration

    def spurious_per_min(self, method: str, rows=None) -> np.ndarray:
        """Pooled over the trials (`rows`: some of them): spurious switches / minutes."""
        counts = self.spurious[method] if rows is None else self.spurious[method][rows]
        minutes = self.minutes if rows is None else self.minutes[rows]
        with np.errstate(all="ignore"):
            return np.array(
                [
                    np.nan if np.isnan(c).any() else c.sum() / minutes.sum()
                    for c in np.atleast_2d(counts).T
                ]
            )


# ---------------------------------------------------------------------------------------
# running methods


def decisions_of(probabilities: np.ndarray) -> np.ndarray:
    """The argmax of each row; -1 (never right) for a row that is not finite."""
    p = np.asarray(probabilities, dtype=float).reshape(len(probabilities), -1)
    out = np.argmax(np.nan_to_num(p, nan=-np.inf), axis=1)
    out[~np.all(np.isfinite(p), axis=1)] = -1
    return out


def run_offline(
    fusion: Fusion, probabilities: np.ndarray, elevation_deg: np.ndarray | None = None
) -> FusionRun:
    """Push every frame through a fresh streaming object, then flush: the live decisions.

    A frame whose probabilities are not finite (a broken classifier) is pushed as uniform,
    carrying no evidence, and left undecided (-1): it is never scored as right. A method
    with gait cues (`uses_gait`) gets each frame's camera elevation, `elevation_deg`."""
    e = np.array(probabilities, dtype=float)
    unusable = ~np.all(np.isfinite(e), axis=1) if e.ndim == 2 else np.zeros(len(e), bool)
    e[unusable] = 1.0 / N_MODES
    n = len(e)
    decisions = np.full(n, -1)
    voted = np.full(n, -1)
    posteriors = np.full((n, N_MODES), np.nan)
    fusion.reset()

    def collect(out) -> None:
        if out is None:
            return
        if out.frame is not None:
            decisions[out.frame] = out.decision
        if out.posterior_frame is not None:
            posteriors[out.posterior_frame] = out.probabilities
        if out.voted_frame is not None:
            voted[out.voted_frame] = out.voted

    if getattr(fusion, "uses_gait", False):
        if elevation_deg is None:
            raise InferenceError(
                f"{fusion.method} needs the camera's orientation at each frame (recordings)"
            )
        for row, elevation in zip(e, np.asarray(elevation_deg, dtype=float).tolist()):
            collect(fusion.push(row, elevation))
    else:
        for row in e:
            collect(fusion.push(row))
    for out in fusion.flush():
        collect(out)
    final = voted if fusion.votes else decisions
    if np.any(final < 0):  # every frame must be decided once flushed
        raise AssertionError(f"{fusion.method}: frames without a decision")
    decisions[unusable] = -1
    if fusion.votes:
        final[unusable] = -1
    return FusionRun(fusion.method, decisions, final, posteriors)


def vote_offline(decisions: np.ndarray, vote_delay: int) -> np.ndarray:
    """The streaming Voter over a decision sequence (pushed, then flushed)."""
    voter = Voter(vote_delay)
    votes = np.full(len(decisions), -1)
    for frame, decision in enumerate(decisions.tolist()):
        vote = voter.push(frame, decision)
        if vote is not None:
            votes[vote[0]] = vote[1]
    for frame, vote in voter.flush():
        votes[frame] = vote
    return votes


def accuracy(decisions: np.ndarray, reference: np.ndarray) -> float:
    """Fraction of frames with a reference whose decision equals it."""
    reference = np.asarray(reference)
    labeled = reference >= 0
    if not labeled.any():
        raise InferenceError("no frame has a reference mode")
    return float(np.mean(np.asarray(decisions)[labeled] == reference[labeled]))


def _per_trial(params: FusionParameters | Sequence[FusionParameters], n: int):
    if isinstance(params, FusionParameters):
        return [params] * n
    if len(params) != n:
        raise ValueError("one FusionParameters per trial")
    return list(params)


def evaluate_trial(
    trial: Trial,
    methods: Sequence[str] = PAPER_METHODS,
    params: FusionParameters = FusionParameters(),
) -> TrialResult:
    if not (trial.reference >= 0).any():
        raise InferenceError(f"{trial.path}: no frame has a reference mode")
    try:
        runs = {
            m: run_offline(params.make(m), trial.probabilities, trial.elevation_deg)
            for m in methods
        }
    except InferenceError as e:
        raise InferenceError(f"{trial.path}: {e}") from None
    return TrialResult(
        trial,
        {m: accuracy(r.final, trial.reference) for m, r in runs.items()},
        runs,
        {m: trial_transitions(trial, r.final, params.delay_frames(m)) for m, r in runs.items()},
    )


def trial_transitions(
    trial: Trial, final: np.ndarray, delay_frames: int
) -> dict[str, tr.TransitionStats]:
    """A decision sequence's switches against each of the trial's references."""
    return {
        name: tr.transition_stats(final, ref, trial.times_s, name=name, delay_frames=delay_frames)
        for name, ref in trial.references().items()
    }


def pooled_transitions(
    results: Sequence[TrialResult], method: str
) -> dict[str, tr.TransitionStats]:
    """Per reference, the trials' switches pooled (counts and minutes summed); a reference
    only some trials have is pooled over those."""
    names: dict[str, list[tr.TransitionStats]] = {}
    for r in results:
        for name, stats in r.transitions.get(method, {}).items():
            names.setdefault(name, []).append(stats)
    return {name: tr.pooled(stats) for name, stats in names.items()}


def evaluate(
    trials: Sequence[Trial],
    methods: Sequence[str] = PAPER_METHODS,
    params: FusionParameters | Sequence[FusionParameters] = FusionParameters(),
) -> list[TrialResult]:
    return [evaluate_trial(t, methods, p) for t, p in zip(trials, _per_trial(params, len(trials)))]


def leave_one_out_transitions(trials: Sequence[Trial], smoothing: float = 1.0) -> list[np.ndarray]:
    """Per trial, the transition matrix counted from the other trials' references
    (from the trial itself when it is the only one)."""
    refs = [t.reference for t in trials]
    if len(refs) == 1:
        return [estimate_transition(refs, smoothing)]
    return [estimate_transition(refs[:i] + refs[i + 1 :], smoothing) for i in range(len(refs))]


# ---------------------------------------------------------------------------------------
# statistics


def mean_sd(values: Sequence[float]) -> tuple[float, float]:
    """Mean and sample SD (n-1; NaN for one value)."""
    v = np.asarray(values, dtype=float)
    if v.size == 0:
        return math.nan, math.nan
    return float(v.mean()), float(v.std(ddof=1)) if v.size > 1 else math.nan


def summarize(results: Sequence[TrialResult], methods: Sequence[str]) -> dict[str, dict]:
    """{"mean": {method: ...}, "sd": {method: ...}} across trials."""
    out: dict[str, dict] = {"mean": {}, "sd": {}}
    for m in methods:
        out["mean"][m], out["sd"][m] = mean_sd([r.accuracy[m] for r in results])
    return out


def paired_t_tests(results: Sequence[TrialResult], methods: Sequence[str]) -> list[PairedTest]:
    """Paired t-test between every two methods over the same trials (scipy.stats.ttest_rel)."""
    from scipy import stats

    tests = []
    for i, a in enumerate(methods):
        for b in methods[i + 1 :]:
            x = np.array([r.accuracy[a] for r in results])
            y = np.array([r.accuracy[b] for r in results])
            t = p = math.nan
            if len(x) >= 2 and np.any(x != y):
                with np.errstate(all="ignore"):
                    res = stats.ttest_rel(x, y)
                t, p = float(res.statistic), float(res.pvalue)
            elif len(x) >= 2:
                p = 1.0  # identical results: no difference at all
            tests.append(PairedTest(a, b, len(x), t, p))
    return tests


def group_results(results: Sequence[TrialResult]) -> dict[tuple[str, str], list[TrialResult]]:
    """Trials grouped by (condition, subject), in first-seen order."""
    groups: dict[tuple[str, str], list[TrialResult]] = {}
    for r in results:
        groups.setdefault((r.trial.condition, r.trial.subject), []).append(r)
    return groups


def by_condition(results: Sequence[TrialResult]) -> dict[str, list[TrialResult]]:
    groups: dict[str, list[TrialResult]] = {}
    for r in results:
        groups.setdefault(r.trial.condition, []).append(r)
    return groups


def confusion_matrix(decisions: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Counts: rows the reference mode, columns the decided mode (frames with a reference
    and a decision; an undecided frame, -1, is in no column)."""
    reference = np.asarray(reference)
    decisions = np.asarray(decisions)
    used = (reference >= 0) & (decisions >= 0)
    counts = np.zeros((N_MODES, N_MODES), dtype=int)
    np.add.at(counts, (reference[used], decisions[used]), 1)
    return counts


def pooled_confusion(results: Sequence[TrialResult], method: str) -> np.ndarray:
    return sum(
        (confusion_matrix(r.runs[method].final, r.trial.reference) for r in results),
        np.zeros((N_MODES, N_MODES), dtype=int),
    )


def delay_sweep(
    trials: Sequence[Trial],
    methods: Sequence[str],
    max_delay: int,
    params: FusionParameters | Sequence[FusionParameters] = FusionParameters(),
) -> DelaySweep:
    """Accuracy against the number of delayed frames D = 0..max_delay (the paper's trade-off).

    cnn+voting: l_v = D; hmm+voting: l_v = D-1 (the HMM adds one frame); fixed-lag: lag = D.
    Methods without a delay parameter (cnn, forward: 0; hmm: 1) keep their accuracy for
    every D at or above their own delay; NaN below it. Beside accuracy, the spurious
    switches (inference.transitions) against the same reference.
    """
    delays = list(range(max_delay + 1))
    acc = {m: np.full((len(trials), len(delays)), np.nan) for m in methods}
    spurious = {m: np.full((len(trials), len(delays)), np.nan) for m in methods}
    minutes = np.zeros(len(trials))
    for i, (trial, p) in enumerate(zip(trials, _per_trial(params, len(trials)))):
        ref = trial.reference
        t = tr.frame_times(len(ref), trial.times_s)
        minutes[i] = tr.duration_minutes(t)

        def score(m, d, final, own_delay, i=i, ref=ref, t=t, name=trial.reference_name) -> None:
            acc[m][i, d] = accuracy(final, ref)
            stats = tr.transition_stats(final, ref, t, name=name, delay_frames=own_delay)
            spurious[m][i, d] = stats.spurious

        stages: dict[str, FusionRun] = {}

        def stage(method: str, stages=stages, p=p, trial=trial) -> FusionRun:
            if method not in stages:
                stages[method] = run_offline(
                    p.make(method), trial.probabilities, trial.elevation_deg
                )
            return stages[method]

        for m in methods:
            if m == "cnn+voting":
                for d in delays:
                    score(m, d, vote_offline(stage("cnn").decisions, d), d)
            elif m == "hmm+voting":
                for d in delays[1:]:
                    score(m, d, vote_offline(stage("hmm").decisions, d - 1), d)
            elif m == "fixed-lag":
                for d in delays:
                    score(
                        m,
                        d,
                        run_offline(FixedLagSmoother(p.transition, d), trial.probabilities).final,
                        d,
                    )
            else:  # no delay parameter: the same decisions at every delay from their own
                own = p.delay_frames(m)
                if own <= max_delay:
                    score(m, own, stage(m).final, own)
                    acc[m][i, own:] = acc[m][i, own]
                    spurious[m][i, own:] = spurious[m][i, own]
    return DelaySweep(delays, acc, spurious, minutes)


# ---------------------------------------------------------------------------------------
# the JSON report (what `walkcap eval --json` prints)


def _num(x: float) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def _nums(d: dict) -> dict:
    return {k: _num(v) for k, v in d.items()}


def _tests_json(tests: Sequence[PairedTest]) -> list[dict]:
    return [{"a": t.a, "b": t.b, "n": t.n, "t": _num(t.t), "p": _num(t.p)} for t in tests]


def report(
    results: Sequence[TrialResult],
    methods: Sequence[str],
    params: FusionParameters,
    sweep: DelaySweep | None = None,
    grouped: bool = False,
) -> dict:
    """{"files": [...], "mean", "sd", "delay_frames", "parameters", ...}; accuracies as
    fractions, null where undefined. grouped adds "groups" (subject x condition) and
    "conditions" (with their own paired t-tests)."""
    files = []
    for r in results:
        entry: dict[str, Any] = {"path": r.trial.path, "frames": len(r.trial.reference)}
        labeled = int((r.trial.reference >= 0).sum())
        if labeled != entry["frames"]:
            entry["labeled_frames"] = labeled
        if grouped:
            entry["subject"] = r.trial.subject
            entry["condition"] = r.trial.condition
        entry["accuracy"] = _nums(r.accuracy)
        entry["references"] = list(r.trial.references())
        entry["transitions"] = {
            m: {name: tr.summary(st) for name, st in r.transitions.get(m, {}).items()}
            for m in methods
        }
        files.append(entry)
    summary = summarize(results, methods)
    scored = sorted({r.trial.reference_name for r in results})
    out: dict[str, Any] = {
        "files": files,
        "accuracy_reference": scored[0] if len(scored) == 1 else scored,
        "mean": _nums(summary["mean"]),
        "sd": _nums(summary["sd"]),
        "transitions": _transitions_json(results, methods),
        "delay_frames": {m: params.delay_frames(m) for m in methods},
        "parameters": {
            "window": params.window,
            "vote_delay": params.vote_delay,
            **({"lag": params.lag} if "fixed-lag" in methods else {}),
            **(
                {"stay": params.stay, "evidence": params.evidence}
                if any(m.startswith("steady") for m in methods)
                else {}
            ),
            **({"hysteresis": params.hysteresis} if "steady+hysteresis" in methods else {}),
        },
    }
    if len(results) >= 2:
        out["paired_t_tests"] = _tests_json(paired_t_tests(results, methods))
    if grouped:
        out["groups"] = []
        for (condition, subject), rs in group_results(results).items():
            s = summarize(rs, methods)
            out["groups"].append(
                {
                    "condition": condition,
                    "subject": subject,
                    "trials": len(rs),
                    "mean": _nums(s["mean"]),
                    "sd": _nums(s["sd"]),
                }
            )
        out["conditions"] = []
        for condition, rs in by_condition(results).items():
            s = summarize(rs, methods)
            out["conditions"].append(
                {
                    "condition": condition,
                    "trials": len(rs),
                    "mean": _nums(s["mean"]),
                    "sd": _nums(s["sd"]),
                    "paired_t_tests": _tests_json(paired_t_tests(rs, methods)),
                    "transitions": _transitions_json(rs, methods),
                }
            )
    if sweep is not None:
        with np.errstate(all="ignore"):
            out["sweep"] = {
                "delays": sweep.delays,
                "mean": {m: [_num(x) for x in _nanmean(a)] for m, a in sweep.accuracy.items()},
                "sd": {m: [_num(x) for x in _nansd(a)] for m, a in sweep.accuracy.items()},
                "spurious_per_min": {
                    m: [_num(x) for x in sweep.spurious_per_min(m)] for m in sweep.spurious
                },
            }
    return out


def _transitions_json(results: Sequence[TrialResult], methods: Sequence[str]) -> dict:
    """method -> reference -> the pooled transition figures (inference.transitions)."""
    return {
        m: {name: tr.summary(st) for name, st in pooled_transitions(results, m).items()}
        for m in methods
    }


def _nanmean(a: np.ndarray) -> np.ndarray:
    return np.array([np.mean(c) if not np.isnan(c).any() else np.nan for c in a.T])


def _nansd(a: np.ndarray) -> np.ndarray:
    return np.array(
        [np.std(c, ddof=1) if len(c) > 1 and not np.isnan(c).any() else np.nan for c in a.T]
    )


# ---------------------------------------------------------------------------------------
# inputs


def read_scores(path: str | Path, fps: float = tr.PAPER_FPS) -> Trial:
    """A score CSV: header LG,US,DS,UR,DR,label, one row per frame in capture order, frames
    `fps` a second. `label` is the terrain reference; an optional last column `locomotion`
    (header LG,US,DS,UR,DR,label,locomotion) the locomotion reference.

    Every problem is a ScoreFileError naming the file and line (1 = the header).
    """
    path = str(path)
    expected = ",".join(SCORE_HEADER)
    probabilities: list[list[float]] = []
    labels: list[int] = []
    locomotion: list[int] = []
    header_fields = SCORE_HEADER
    with open(path, newline="", encoding="utf-8-sig") as f:
        rows = csv.reader(f)
        try:
            header = next(rows, None)
            if header is None or not any(h.strip() for h in header):
                raise ScoreFileError(
                    f"{path}: empty file (expected the header {expected} and one row per frame)"
                )
            header_fields = tuple(h.strip() for h in header)
            if header_fields not in (SCORE_HEADER, SCORE_HEADER_LOCOMOTION):
                raise ScoreFileError(
                    f"{path}:1: expected the header {expected} (optionally ,locomotion), "
                    f"got {','.join(header)}"
                )
            for row in rows:
                line = rows.line_num
                if not row or not any(c.strip() for c in row):
                    continue  # blank lines (often one at the end)
                probabilities.append(_score_row(path, line, row, header_fields))
                for column, into in zip(row[N_MODES:], (labels, locomotion)):
                    label = column.strip()
                    if label not in MODES:
                        name = "label" if into is labels else "locomotion"
                        raise ScoreFileError(
                            f"{path}:{line}: unknown {name} {label!r} "
                            f"(expected one of {', '.join(MODES)})"
                        )
                    into.append(MODES.index(label))
        except csv.Error as e:
            raise ScoreFileError(f"{path}:{rows.line_num}: not valid CSV: {e}") from None
        except UnicodeDecodeError:
            raise ScoreFileError(f"{path}: not a text file (expected CSV)") from None
    if not probabilities:
        raise ScoreFileError(f"{path}: no frames after the header")
    n = len(probabilities)
    return Trial(
        path,
        np.array(probabilities),
        np.array(labels),
        times_s=np.arange(n) / fps,
        locomotion=np.array(locomotion) if locomotion else None,
    )


def _score_row(
    path: str, line: int, row: list[str], header: tuple[str, ...] = SCORE_HEADER
) -> list[float]:
    if len(row) != len(header):
        raise ScoreFileError(
            f"{path}:{line}: expected {len(header)} fields ({','.join(header)}), got {len(row)}"
        )
    values = []
    for name, text in zip(MODES, row):
        try:
            v = float(text)
        except ValueError:
            raise ScoreFileError(f"{path}:{line}: {name}: not a number: {text.strip()!r}") from None
        if not math.isfinite(v):
            raise ScoreFileError(f"{path}:{line}: {name}: not a finite number: {text.strip()}")
        if v < 0:
            raise ScoreFileError(f"{path}:{line}: {name}: negative probability {v:g}")
        values.append(v)
    total = sum(values)
    if abs(total - 1.0) > SUM_TOLERANCE:
        raise ScoreFileError(
            f"{path}:{line}: probabilities sum to {total:.4g}, expected 1 (within {SUM_TOLERANCE})"
        )
    return values


REFERENCES = ("terrain", "locomotion")
# the names `eval --reference` took before the two references had names
_REFERENCE_ALIASES = {"truth": "terrain", "labels": "locomotion", "auto": "terrain"}


def trial_from_recording(path: str, data: Any, reference: str = "terrain") -> Trial:
    """A Trial from what `capture.recording.reader.read_trial` returns for one recording.

    data: a mapping (or object) with "probabilities" (N, 5), "terrain" (N modes each image
    shows, or None; a flat dict may give "truth" instead), "locomotion" (N modes keyed live,
    -1/None before the first key; or "labels"), "time_ns" and "metadata" (capture's
    {"session": {...}}, or a flat dict). reference: what accuracy is scored against,
    "terrain" or "locomotion"; the other one, when present, serves the transition metrics.
    Frames without a finite CNN output are left out.
    """

    def get(key: str):
        return data.get(key) if isinstance(data, dict) else getattr(data, key, None)

    def has(key: str) -> bool:
        return key in data if isinstance(data, dict) else hasattr(data, key)

    reference = _REFERENCE_ALIASES.get(reference, reference)
    if reference not in REFERENCES:
        raise InferenceError(f"unknown reference {reference!r} (known: {', '.join(REFERENCES)})")
    terrain = get("terrain") if has("terrain") else get("truth")
    locomotion = get("locomotion") if has("locomotion") else get("labels")

    def usable(seq) -> bool:
        return seq is not None and bool((mode_indices(seq) >= 0).any())

    if reference == "terrain" and not usable(terrain):
        raise InferenceError(
            f"{path}: no terrain reference (what the images show) to score accuracy against: "
            "label the images in `walkcap replay FILE --tui`, or score against the live keys "
            "with --reference locomotion"
        )
    if reference == "locomotion" and not usable(locomotion):
        raise InferenceError(f"{path}: no locomotion labels (keyed live) to compare with")
    chosen = mode_indices(terrain if reference == "terrain" else locomotion)
    second = mode_indices(locomotion) if reference == "terrain" and usable(locomotion) else None
    metadata = dict(get("metadata") or {})
    metadata = {**metadata, **(metadata.get("session") or {})}  # capture nests the form
    probabilities = np.asarray(get("probabilities"), dtype=float)
    times = get("time_ns")
    times_s = None
    if times is not None and len(times) == len(chosen) and len(times):
        t = np.asarray(times, dtype=np.int64)
        times_s = (t - t[0]) * 1e-9
    elevation = get("camera_elevation_deg")
    if elevation is not None:
        elevation = np.asarray(elevation, dtype=float)
    finite = np.isfinite(probabilities).all(axis=1) if probabilities.ndim == 2 else None
    if finite is not None and not finite.all():
        log.warning("%s: %d frame(s) without a CNN output left out", path, (~finite).sum())
        probabilities, chosen = probabilities[finite], chosen[finite]
        second = second[finite] if second is not None else None
        times_s = times_s[finite] if times_s is not None else None
        elevation = elevation[finite] if elevation is not None else None
    return Trial(str(path), probabilities, chosen, metadata, times_s, reference, second, elevation)


def synthetic_trial(
    seed: int = 0,
    accuracy: float = 0.9,
    block_frames: tuple[int, int] = (30, 80),
    path: str = "",
    metadata: dict | None = None,
) -> Trial:
    """A simulated trial for tests and demos: the paper's course (three level-ground
    blocks, stairs and ramps up and down) and CNN-like scores that pick the true mode on
    about `accuracy` of the frames, errors independent and less confident."""
    rng = np.random.default_rng(seed)
    course = ["LG", "US", "LG", "UR", "LG", "DS", "DR"]
    reference = np.concatenate(
        [np.full(rng.integers(*block_frames), MODES.index(m)) for m in course]
    )
    n = len(reference)
    chosen = reference.copy()
    wrong = rng.random(n) > accuracy
    chosen[wrong] = (reference[wrong] + rng.integers(1, N_MODES, wrong.sum())) % N_MODES
    confidence = np.where(wrong, rng.uniform(0.35, 0.7, n), rng.uniform(0.55, 0.99, n))
    rest = rng.dirichlet(np.ones(N_MODES - 1), n) * (1 - confidence)[:, None]
    probabilities = np.empty((n, N_MODES))
    for i in range(n):
        probabilities[i, chosen[i]] = confidence[i]
        probabilities[i, np.arange(N_MODES) != chosen[i]] = rest[i]
    return Trial(path or f"synthetic-{seed}", probabilities, reference, dict(metadata or {}))


# ---------------------------------------------------------------------------------------
# figures (matplotlib: vector PDF and 300-dpi PNG)

# A figure is as wide as one column of a two-column paper (3.5 in) and is printed at that
# size: every text at 6 pt or more.
COLUMN_IN = 3.5
FIGURE_STYLE = {
    "font.size": 7,
    "axes.titlesize": 7.5,
    "axes.labelsize": 7,
    "xtick.labelsize": 6.5,
    "ytick.labelsize": 6.5,
    "legend.fontsize": 6.5,
    "legend.title_fontsize": 6.5,
    "figure.titlesize": 8,
    "axes.linewidth": 0.6,
    "lines.linewidth": 1.0,
    "hatch.linewidth": 0.6,
    "pdf.fonttype": 42,  # text stays text in the PDF
}
# Methods are told apart by grey level, hatch, marker and dash, never by a mode's colour
# (colour means a mode on every screen and figure: devices.frames.MODE_COLORS).
METHOD_STYLES = {  # shade: the method (light CNN, dark HMM); hatch: with voting
    "cnn": {"color": "#e4e4e4", "hatch": "", "line": "#a8a8a8", "marker": "o", "linestyle": ":"},
    "cnn+voting": {
        "color": "#bcbcbc",
        "hatch": "////",
        "hatchcolor": "#4a4a4a",
        "line": "#7c7c7c",
        "marker": "s",
        "linestyle": "-.",
    },
    "hmm": {"color": "#6a6a6a", "hatch": "", "line": "#505050", "marker": "D", "linestyle": "--"},
    "hmm+voting": {
        "color": "#262626",
        "hatch": "////",
        "hatchcolor": "#d0d0d0",
        "line": "#000000",
        "marker": "^",
        "linestyle": "-",
    },
}
# the streaming smoothers: white or mid grey, with hatches of their own
METHOD_STYLES |= {
    "steady": {
        "color": "#ffffff",
        "hatch": "xxxx",
        "line": "#303030",
        "marker": "v",
        "linestyle": (0, (5, 1, 1, 1)),
    },
    "steady+gait": {
        "color": "#949494",
        "hatch": "\\\\\\\\",
        "hatchcolor": "#000000",
        "line": "#202020",
        "marker": "P",
        "linestyle": (0, (3, 1, 1, 1, 1, 1)),
    },
    "forward": {
        "color": "#ffffff",
        "hatch": "....",
        "line": "#606060",
        "marker": "X",
        "linestyle": (0, (1, 1)),
    },
    "steady+hysteresis": {
        "color": "#b4b4b4",
        "hatch": "++++",
        "hatchcolor": "#000000",
        "line": "#101010",
        "marker": "h",
        "linestyle": (0, (8, 2, 2, 2)),
    },
    "fixed-lag": {
        "color": "#d8d8d8",
        "hatch": "----",
        "line": "#404040",
        "marker": "p",
        "linestyle": (0, (6, 2)),
    },
}
_SPARE_STYLES = (
    {
        "color": "#909090",
        "hatch": "xxxx",
        "line": "#606060",
        "marker": "v",
        "linestyle": (0, (5, 1, 1, 1)),
    },
    {
        "color": "#d0d0d0",
        "hatch": "....",
        "line": "#909090",
        "marker": "*",
        "linestyle": (0, (1, 1)),
    },
)
FOOTNOTE_CHARS = 80  # characters a line of 6-pt text holds across one column
GAP_PERIODS = 3  # frames farther apart than this many frame periods: a gap, nothing drawn


def method_style(method: str, k: int = 0) -> dict:
    return METHOD_STYLES.get(method) or _SPARE_STYLES[k % len(_SPARE_STYLES)]


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "trial"


def write_plots(
    results: Sequence[TrialResult],
    out_dir: str | Path,
    methods: Sequence[str],
    params: FusionParameters = FusionParameters(),
    sweep: DelaySweep | None = None,
    trials: Sequence[str] | None = None,
) -> list[Path]:
    """The paper's figures in out_dir, each as a vector PDF and a 300-dpi PNG, one column
    (3.5 in) wide; returns the files written.

    accuracy_per_subject[_<condition>] (mean and SD over each subject's trials, per
    method), accuracy_vs_delay (with a sweep; mean and SD over trials, and spurious
    switches a minute below), switches (per condition, each method's accuracy against its
    spurious switches a minute, the trade-off, with its delay), decisions_<trial>
    and probabilities_<trial> (every trial, or those whose file name or title contains
    one of `trials`), confusion[_<condition>] (row-normalised, with counts).
    Time is in seconds from the trial's first frame when the trial has frame times; where
    frames are missing (more than GAP_PERIODS frame periods apart) nothing is drawn.
    Modes have their colours of the live screen (devices.frames.MODE_COLORS).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []

    def save(fig, name: str) -> None:
        for suffix, kwargs in ((".pdf", {}), (".png", {"dpi": 300})):
            path = out / f"{name}{suffix}"
            fig.savefig(path, bbox_inches="tight", pad_inches=0.02, **kwargs)
            written.append(path)
        plt.close(fig)

    with plt.rc_context(FIGURE_STYLE):
        conditions = by_condition(results)
        for condition, rs in conditions.items():
            suffix = f"_{_safe(condition)}" if condition else ""
            save(_plot_per_subject(plt, rs, methods, condition), f"accuracy_per_subject{suffix}")
        if sweep is not None:
            save(_plot_sweep(plt, results, sweep), "accuracy_vs_delay")
        save(_plot_switches(plt, results, methods, params), "switches")
        for r in results:
            name = Path(r.trial.path).stem
            if trials and not any(t in name or t in r.trial.title for t in trials):
                continue
            stem = _safe(name)
            save(_plot_decisions(plt, r, methods), f"decisions_{stem}")
            save(_plot_probabilities(plt, r, params), f"probabilities_{stem}")
        for condition, rs in conditions.items():
            suffix = f"_{_safe(condition)}" if condition else ""
            save(_plot_confusion(plt, rs, methods, condition), f"confusion{suffix}")
    return written


def _sd_clipped(means: np.ndarray, sds: np.ndarray) -> np.ndarray:
    """Error bars of mean +- SD in %, cut at 0 and 100 (accuracy cannot pass them); NaN
    (no bar) where the SD is undefined (a single trial)."""
    return np.vstack([np.minimum(sds, means), np.minimum(sds, 100 - means)])


def _axis_floor(lowest: float) -> float:
    """Where an accuracy axis starts: a multiple of 5 % a little under the lowest value
    shown (bars of 95-99 % on a 0-100 % axis show no difference), 0 at the least."""
    return max(0.0, 5 * math.floor((lowest - 1.0) / 5)) if math.isfinite(lowest) else 0.0


def _legend_below(fig, ax, ncol: int, note: str = "", **kwargs) -> None:
    """The legend under the axes, never over the data (a column is too narrow for one
    beside them); `note`, what the marks mean, under the legend."""
    legend = fig.legend(
        *ax.get_legend_handles_labels(),
        loc="upper center",
        bbox_to_anchor=(0.5, 0.0),
        ncol=ncol,
        frameon=False,
        handlelength=2.2,
        columnspacing=1.0,
        **kwargs,
    )
    if note:
        _footnote(fig, note, under=legend)


def _footnote(fig, text: str, under=None) -> None:
    """A note across the column's width under the figure (or under the artist `under`,
    placed when the figure is drawn), at the smallest size a printed figure allows."""
    from matplotlib.text import Annotation

    fig.add_artist(
        Annotation(
            textwrap.fill(text, FOOTNOTE_CHARS),
            xy=(0.0, 0.0),
            xycoords=("figure fraction", under if under is not None else "figure fraction"),
            xytext=(0, -3),
            textcoords="offset points",
            ha="left",
            va="top",
            fontsize=6,
        )
    )


def _plot_per_subject(plt, results, methods, condition):
    groups = group_results(results)
    subjects = [f"{s}\n(n = {len(rs)})" for (_, s), rs in groups.items()]
    fig, ax = plt.subplots(figsize=(COLUMN_IN, 2.3), layout="constrained")
    width = 0.84 / len(methods)
    x = np.arange(len(subjects))
    lowest, labels = 100.0, []
    for k, m in enumerate(methods):
        stats = [mean_sd([r.accuracy[m] for r in rs]) for rs in groups.values()]
        means = np.array([100 * st[0] for st in stats])
        sds = np.array([100 * st[1] for st in stats])
        bars = _sd_clipped(means, sds)
        style = method_style(m, k)
        xs = x + (k - (len(methods) - 1) / 2) * width
        ax.bar(
            xs,
            means,
            width,
            yerr=bars,
            capsize=1.5,
            error_kw={"linewidth": 0.6, "capthick": 0.6},
            color=style["color"],
            hatch=style["hatch"],
            hatchcolor=style.get("hatchcolor", "black"),
            edgecolor="black",
            linewidth=0.5,
            label=TITLES.get(m, m),
        )
        low = means - np.nan_to_num(bars[0])
        if np.isfinite(low).any():
            lowest = min(lowest, float(np.nanmin(low)))
        labels += [(xi, mi, mi + np.nan_to_num(b)) for xi, mi, b in zip(xs, means, bars[1])]
    floor = _axis_floor(lowest)
    span = 100.0 - floor
    for xi, mean, top in labels:  # the value of each bar, above its error bar
        if math.isfinite(mean):
            ax.text(
                xi,
                top + 0.015 * span,
                f"{mean:.1f}",
                rotation=90,
                ha="center",
                va="bottom",
                fontsize=6,
            )
    ax.set_ylim(floor, 100.0 + 0.3 * span)  # room for the values over a 100 % bar
    ax.set_yticks([v for v in ax.get_yticks() if floor <= v <= 100])
    ax.set_xticks(x, subjects)
    ax.set_xlabel("subject (number of trials)")
    ax.set_ylabel("accuracy (%)")
    where = f", {condition}" if condition else ""
    ax.set_title(f"Accuracy per subject{where}: mean ± SD over trials")
    ax.set_ylabel(f"accuracy against {_reference_of(results)} (%)")
    _legend_below(
        fig,
        ax,
        ncol=min(4, len(methods)),
        note="Error bars: standard deviation across the subject's trials, cut at 0 and 100 %; "
        "none for a single trial.",
    )
    return fig


def _plot_sweep(plt, results, sweep):
    conditions = by_condition(results)
    index = {id(r): i for i, r in enumerate(results)}
    fig, axes = plt.subplots(
        2,
        len(conditions),
        figsize=(COLUMN_IN, 3.4),
        squeeze=False,
        sharex=True,
        sharey="row",
        height_ratios=(3, 2),
        layout="constrained",
    )
    lowest = 100.0
    for col, (condition, rs) in enumerate(conditions.items()):
        ax, low = axes[0][col], axes[1][col]
        rows = [index[id(r)] for r in rs]
        for k, (m, a) in enumerate(sweep.accuracy.items()):
            sub = a[rows]
            with np.errstate(all="ignore"):
                mean, sd = 100 * _nanmean(sub), 100 * _nansd(sub)
            bars = _sd_clipped(np.nan_to_num(mean), sd)
            if np.isfinite(mean).any():
                lowest = min(lowest, float(np.nanmin(mean - np.nan_to_num(bars[0]))))
            style = method_style(m, k)
            dodge = (k - (len(sweep.accuracy) - 1) / 2) * 0.09  # methods that agree stay apart
            x = np.asarray(sweep.delays, dtype=float) + dodge
            look = dict(
                color=style["line"],
                marker=style["marker"],
                markersize=3.5,
                markeredgecolor="black",
                markeredgewidth=0.4,
                linestyle=style["linestyle"],
                label=TITLES.get(m, m),
            )
            ax.errorbar(x, mean, yerr=bars, capsize=1.5, elinewidth=0.6, **look)
            if m in sweep.spurious:
                low.plot(x, sweep.spurious_per_min(m, rows), **look)
        low.set_xticks(sweep.delays)
        low.set_xlabel("decision delay (frames)")
        n = len(rs)
        ax.set_title(f"{condition or 'all trials'} (n = {n} trial{'s' if n != 1 else ''})")
    reference = _reference_of(results)
    axes[0][0].set_ylim(_axis_floor(lowest), 100)
    axes[1][0].set_ylim(bottom=0)  # once every condition is drawn: the row shares it
    axes[0][0].set_ylabel("accuracy (%)\nmean ± SD")
    axes[1][0].set_ylabel("spurious\nswitches / min")
    fig.suptitle(f"Accuracy and spurious switches against delay ({reference} reference)")
    _legend_below(
        fig,
        axes[0][0],
        ncol=min(4, len(sweep.accuracy)),
        note="Error bars: SD across trials, cut at 100 %. Delay d: a frame's decision is made "
        f"d frames later. Spurious switches: decision changes where the {reference} "
        "reference did not change, pooled over trials.",
    )
    return fig


def _reference_of(results) -> str:
    names = sorted({r.trial.reference_name for r in results})
    return " / ".join(names) or "terrain"


def _plot_switches(plt, results, methods, params):
    """Per condition (one panel each, stacked): each method's accuracy (mean over trials)
    against its spurious switches a minute (pooled), with its delay: the trade-off a
    controller feels."""
    conditions = by_condition(results)
    fig, axes = plt.subplots(
        len(conditions),
        1,
        figsize=(COLUMN_IN, 0.4 + 1.6 * len(conditions)),
        squeeze=False,
        sharex=True,
        layout="constrained",
    )
    reference = _reference_of(results)
    for (ax,), (condition, rs) in zip(axes, conditions.items()):
        for k, m in enumerate(methods):
            stats = pooled_transitions(rs, m).get(reference)
            if stats is None:
                continue
            style = method_style(m, k)
            ax.plot(
                stats.spurious_per_min,
                100 * mean_sd([r.accuracy[m] for r in rs])[0],
                marker=style["marker"],
                color=style["line"],
                markeredgecolor="black",
                markeredgewidth=0.4,
                linestyle="none",
                markersize=4.5,
                label=f"{TITLES.get(m, m)} ({params.delay_frames(m)} fr)",
            )
        ax.set_ylabel("accuracy (%)")
        ax.grid(True, linewidth=0.3)
        n = len(rs)
        ax.set_title(f"{condition or 'all trials'} (n = {n} trial{'s' if n != 1 else ''})")
    for (ax,) in axes:  # a point at 0 shows whole, on one scale for every condition
        right = max(1.0, ax.get_xlim()[1])
        ax.set_xlim(-0.04 * right, right)
    axes[-1][0].set_xlabel("spurious switches a minute")
    fig.suptitle(f"Accuracy against spurious switches ({reference} reference)")
    _legend_below(
        fig,
        axes[0][0],
        ncol=2,
        title="method (delay in frames); up and left is better",
        note="Accuracy: mean over trials. Spurious switches: decision changes with no change "
        "of the reference to that mode within 2 s, pooled over trials.",
    )
    return fig


def _time_axis(trial: Trial) -> tuple[np.ndarray, str]:
    if trial.times_s is not None and len(trial.times_s) == len(trial.reference):
        return trial.times_s, "time (s)"
    return np.arange(len(trial.reference), dtype=float), "frame"


def _frame_period(t: np.ndarray) -> float:
    steps = np.diff(t)
    steps = steps[steps > 0]
    return float(np.median(steps)) if len(steps) else 1.0


def gap_breaks(t: np.ndarray) -> np.ndarray:
    """Indices i where frames i and i+1 are a gap apart (missing frames, a stall)."""
    if len(t) < 2:
        return np.zeros(0, dtype=int)
    return np.flatnonzero(np.diff(t) > GAP_PERIODS * _frame_period(t))


def _runs(t: np.ndarray, values: np.ndarray):
    """(start, end, value) of each run of equal values that no gap interrupts; a frame
    spans one frame period from its time; -1 (none) is no run."""
    period = _frame_period(t)
    cut = np.zeros(len(t), dtype=bool)
    cut[gap_breaks(t) + 1] = True
    start = 0
    for i in range(1, len(t) + 1):
        if i == len(t) or cut[i] or values[i] != values[start]:
            if values[start] >= 0:
                yield t[start], t[i - 1] + period, int(values[start])
            start = i


def _with_gaps(t: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """t and values with a NaN row inserted in every gap, so that lines break there."""
    breaks = gap_breaks(t)
    if not len(breaks):
        return t, values
    t2 = np.insert(t.astype(float), breaks + 1, np.nan)
    v2 = np.insert(values.astype(float), breaks + 1, np.nan, axis=0)
    return t2, v2


def _mode_legend(fig, none: str = "") -> None:
    """The modes' colours with their letters, under the figure; `none`: what white means."""
    from matplotlib.patches import Patch

    handles = [Patch(facecolor=MODE_COLORS[m], label=m) for m in MODES]
    if none:
        handles.append(Patch(facecolor="white", edgecolor="#888888", linewidth=0.5, label=none))
    fig.legend(
        handles=handles,
        loc="upper center",
        bbox_to_anchor=(0.5, 0.0),
        ncol=len(handles),
        frameon=False,
        handlelength=1.2,
        columnspacing=0.9,
    )


def _plot_decisions(plt, result, methods):
    """The paper's Fig. 8 as the live screen draws it: one strip per source (reference,
    then each method), coloured by mode; white where there is no frame or no decision."""
    trial = result.trial
    t, xlabel = _time_axis(trial)
    rows = [(f"{trial.reference_name}\n(reference)", trial.reference)]
    if trial.locomotion is not None and trial.reference_name != "locomotion":
        rows.append(("locomotion\n(keyed live)", trial.locomotion))
    rows += [
        (f"{TITLES.get(m, m)}\n{100 * result.accuracy[m]:.1f} %", result.runs[m].final)
        for m in methods
    ]
    fig, ax = plt.subplots(figsize=(COLUMN_IN, 0.35 * len(rows) + 0.9), layout="constrained")
    for k, (_, values) in enumerate(rows):
        y = len(rows) - 1 - k
        by_mode: dict[int, list] = {}
        for start, end, mode in _runs(t, np.asarray(values)):
            by_mode.setdefault(mode, []).append((start, end - start))
        for mode, spans in by_mode.items():  # one shape per mode and strip: quick to draw
            ax.broken_barh(
                spans, (y - 0.38, 0.76), facecolors=MODE_COLORS[MODES[mode]], linewidth=0
            )
    ax.set_yticks(range(len(rows)), [name for name, _ in reversed(rows)])
    ax.set_ylim(-0.6, len(rows) - 0.4)
    ax.set_xlabel(xlabel)
    ax.set_xlim(t[0] if len(t) else 0, (t[-1] + _frame_period(t)) if len(t) else 1)
    ax.tick_params(axis="y", length=0)
    for side in ("left", "right", "top"):
        ax.spines[side].set_visible(False)
    ax.set_title(f"Sequential decisions: {trial.title}\n(accuracy against {trial.reference_name})")
    _mode_legend(fig, none="none")
    return fig


def _plot_probabilities(plt, result, params):
    trial = result.trial
    t, xlabel = _time_axis(trial)
    run = result.runs.get("hmm") or result.runs.get("hmm+voting")
    if run is None:
        run = run_offline(HmmFusion(params.window, params.transition), trial.probabilities)
    fig, axes = plt.subplots(2, 1, figsize=(COLUMN_IN, 2.9), sharex=True, layout="constrained")
    for ax, p, title in (
        (axes[0], trial.probabilities, "CNN softmax output"),
        (axes[1], run.posteriors, f"HMM smoothed posterior (window {params.window} frames)"),
    ):
        tt, pp = _with_gaps(t, np.asarray(p, dtype=float))
        for j, mode in enumerate(MODES):
            ax.plot(tt, pp[:, j], label=mode, linewidth=0.8, color=MODE_COLORS[mode])
        ax.set_ylim(0, 1.02)
        ax.set_ylabel("probability")
        ax.set_title(title)
    axes[1].set_xlabel(xlabel)
    axes[1].set_xlim(t[0] if len(t) else 0, t[-1] if len(t) else 1)
    fig.suptitle(f"Probability traces: {trial.title}")
    _mode_legend(fig)
    return fig


def _plot_confusion(plt, results, methods, condition=""):
    cols = 2 if len(methods) > 1 else 1
    grid = math.ceil(len(methods) / cols)
    fig, axes = plt.subplots(
        grid,
        cols,
        figsize=(COLUMN_IN, 1.5 * grid + 0.45),
        squeeze=False,
        layout="constrained",
    )
    image = None
    for ax in axes.flat[len(methods) :]:
        ax.set_visible(False)
    for ax, m in zip(axes.flat, methods):
        counts = pooled_confusion(results, m)
        with np.errstate(all="ignore"):
            rate = 100 * counts / counts.sum(axis=1, keepdims=True)
        image = ax.imshow(np.nan_to_num(rate), vmin=0, vmax=100, cmap="Greys")
        for i in range(N_MODES):
            for j in range(N_MODES):
                if counts[i].sum() == 0:
                    continue
                ax.text(
                    j,
                    i,
                    f"{rate[i, j]:.0f}",
                    ha="center",
                    va="center",
                    fontsize=6.5,
                    color="white" if rate[i, j] > 55 else "black",
                )
        rows = [f"{mode} {counts[i].sum()}" for i, mode in enumerate(MODES)]
        ax.set_xticks(range(N_MODES), MODES)
        ax.set_yticks(range(N_MODES), rows)
        ax.tick_params(length=0, pad=1.5)
        ax.set_xlabel("decided", labelpad=1)
        ax.set_title(TITLES.get(m, m))
    for row in axes:
        row[0].set_ylabel("reference, frames", labelpad=1)
    bar = fig.colorbar(image, ax=axes, fraction=0.04, pad=0.02, shrink=0.8)
    bar.set_label("% of the reference row")
    n = len(results)
    where = condition or "all trials"
    fig.suptitle(
        f"Confusion, {where} (n = {n} trial{'s' if n != 1 else ''}),\n"
        f"against the {_reference_of(results)} reference: row %"
    )
    return fig
