"""Evaluating classifiers and fusion the way the paper does: per-frame accuracy per trial,
mean +- SD across trials, paired t-tests, accuracy against delay, confusion matrices.

Decisions always come from the streaming objects of `inference.fusion`, pushed frame by
frame and flushed at the end (`run_offline`): offline results are the live ones.
Accuracy is the fraction of frames whose final decision equals the reference, over the
frames that have a reference (-1 = none); the mean over trials is the mean of the trials'
accuracies, as in the paper (not pooled over frames); SD uses n-1.

Inputs: score files (CSV, `read_scores`) or recordings (capture.reader.read_trials turns
each into a Trial with `trial_from_recording`), both as `Trial`s.
"""

from __future__ import annotations

import csv
import logging
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from devices.frames import MODE_COLORS, MODES
from inference.errors import InferenceError
from inference.fusion import (
    N_MODES,
    PAPER_TRANSITION,
    FixedLagSmoother,
    Fusion,
    HmmFusion,
    Voter,
    estimate_transition,
    make_fusion,
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
}
SCORE_HEADER = (*MODES, "label")
SUM_TOLERANCE = 0.01  # score rows must sum to 1 within this (they are often rounded)


class ScoreFileError(InferenceError):
    """A score CSV is malformed; the message names the file and line."""


@dataclass(frozen=True)
class FusionParameters:
    window: int = 5  # l_w
    vote_delay: int = 1  # l_v
    transition: np.ndarray = field(default_factory=lambda: PAPER_TRANSITION.copy())
    lag: int = 1  # fixed-lag smoother only

    def make(self, method: str) -> Fusion:
        return make_fusion(method, self.window, self.vote_delay, self.transition, self.lag)

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


@dataclass
class PairedTest:
    a: str
    b: str
    n: int
    t: float  # NaN when undefined (fewer than 2 trials, identical results)
    p: float


@dataclass
class DelaySweep:
    """Accuracy per trial against the number of delayed frames (NaN: not reachable)."""

    delays: list[int]
    accuracy: dict[str, np.ndarray]  # method -> (trials, delays)


# ---------------------------------------------------------------------------------------
# running methods


def decisions_of(probabilities: np.ndarray) -> np.ndarray:
    """The argmax of each row; -1 (never right) for a row that is not finite."""
    p = np.asarray(probabilities, dtype=float).reshape(len(probabilities), -1)
    out = np.argmax(np.nan_to_num(p, nan=-np.inf), axis=1)
    out[~np.all(np.isfinite(p), axis=1)] = -1
    return out


def run_offline(fusion: Fusion, probabilities: np.ndarray) -> FusionRun:
    """Push every frame through a fresh streaming object, then flush: the live decisions.

    A frame whose probabilities are not finite (a broken classifier) is pushed as uniform,
    carrying no evidence, and left undecided (-1): it is never scored as right."""
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
    runs = {m: run_offline(params.make(m), trial.probabilities) for m in methods}
    return TrialResult(
        trial, {m: accuracy(r.final, trial.reference) for m, r in runs.items()}, runs
    )


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
    every D at or above their own delay; NaN below it.
    """
    delays = list(range(max_delay + 1))
    acc = {m: np.full((len(trials), len(delays)), np.nan) for m in methods}
    for i, (trial, p) in enumerate(zip(trials, _per_trial(params, len(trials)))):
        ref = trial.reference
        stages: dict[str, FusionRun] = {}

        def stage(method: str, stages=stages, p=p, trial=trial) -> FusionRun:
            if method not in stages:
                stages[method] = run_offline(p.make(method), trial.probabilities)
            return stages[method]

        for m in methods:
            if m in ("cnn", "forward", "hmm"):
                acc[m][i, p.delay_frames(m) :] = accuracy(stage(m).final, ref)
            elif m == "cnn+voting":
                for d in delays:
                    acc[m][i, d] = accuracy(vote_offline(stage("cnn").decisions, d), ref)
            elif m == "hmm+voting":
                for d in delays[1:]:
                    acc[m][i, d] = accuracy(vote_offline(stage("hmm").decisions, d - 1), ref)
            elif m == "fixed-lag":
                for d in delays:
                    run = run_offline(FixedLagSmoother(p.transition, d), trial.probabilities)
                    acc[m][i, d] = accuracy(run.final, ref)
            else:
                raise InferenceError(f"unknown method {m!r}")
    return DelaySweep(delays, acc)


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
        files.append(entry)
    summary = summarize(results, methods)
    out: dict[str, Any] = {
        "files": files,
        "mean": _nums(summary["mean"]),
        "sd": _nums(summary["sd"]),
        "delay_frames": {m: params.delay_frames(m) for m in methods},
        "parameters": {
            "window": params.window,
            "vote_delay": params.vote_delay,
            **({"lag": params.lag} if "fixed-lag" in methods else {}),
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
                }
            )
    if sweep is not None:
        with np.errstate(all="ignore"):
            out["sweep"] = {
                "delays": sweep.delays,
                "mean": {m: [_num(x) for x in _nanmean(a)] for m, a in sweep.accuracy.items()},
                "sd": {m: [_num(x) for x in _nansd(a)] for m, a in sweep.accuracy.items()},
            }
    return out


def _nanmean(a: np.ndarray) -> np.ndarray:
    return np.array([np.mean(c) if not np.isnan(c).any() else np.nan for c in a.T])


def _nansd(a: np.ndarray) -> np.ndarray:
    return np.array(
        [np.std(c, ddof=1) if len(c) > 1 and not np.isnan(c).any() else np.nan for c in a.T]
    )


# ---------------------------------------------------------------------------------------
# inputs


def read_scores(path: str | Path) -> Trial:
    """A score CSV: header LG,US,DS,UR,DR,label, one row per frame in capture order.

    Every problem is a ScoreFileError naming the file and line (1 = the header).
    """
    path = str(path)
    expected = ",".join(SCORE_HEADER)
    probabilities: list[list[float]] = []
    labels: list[int] = []
    with open(path, newline="", encoding="utf-8-sig") as f:
        rows = csv.reader(f)
        try:
            header = next(rows, None)
            if header is None or not any(h.strip() for h in header):
                raise ScoreFileError(
                    f"{path}: empty file (expected the header {expected} and one row per frame)"
                )
            if tuple(h.strip() for h in header) != SCORE_HEADER:
                raise ScoreFileError(
                    f"{path}:1: expected the header {expected}, got {','.join(header)}"
                )
            for row in rows:
                line = rows.line_num
                if not row or not any(c.strip() for c in row):
                    continue  # blank lines (often one at the end)
                probabilities.append(_score_row(path, line, row))
                label = row[N_MODES].strip()
                if label not in MODES:
                    raise ScoreFileError(
                        f"{path}:{line}: unknown label {label!r} "
                        f"(expected one of {', '.join(MODES)})"
                    )
                labels.append(MODES.index(label))
        except csv.Error as e:
            raise ScoreFileError(f"{path}:{rows.line_num}: not valid CSV: {e}") from None
        except UnicodeDecodeError:
            raise ScoreFileError(f"{path}: not a text file (expected CSV)") from None
    if not probabilities:
        raise ScoreFileError(f"{path}: no frames after the header")
    return Trial(path, np.array(probabilities), np.array(labels))


def _score_row(path: str, line: int, row: list[str]) -> list[float]:
    if len(row) != len(SCORE_HEADER):
        raise ScoreFileError(
            f"{path}:{line}: expected {len(SCORE_HEADER)} fields "
            f"({','.join(SCORE_HEADER)}), got {len(row)}"
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


def trial_from_recording(path: str, data: Any, reference: str = "auto") -> Trial:
    """A Trial from what `capture.reader.read_trial` returns for one recording.

    data: a mapping (or object) with "probabilities" (N, 5), "labels" (N operator modes in
    force at each frame: indices or names, -1/None where unlabeled), "truth" (N simulator
    modes, or None) and "metadata" (capture's {"session": {"subject", "condition", ...}},
    or a flat dict). reference: "labels", "truth" or "auto" (operator labels when there
    are any, else simulator truth). Frames without a finite CNN output are left out.
    """

    def get(key: str):
        return data.get(key) if isinstance(data, dict) else getattr(data, key, None)

    labels, truth = get("labels"), get("truth")

    def usable(seq) -> bool:
        return seq is not None and bool((mode_indices(seq) >= 0).any())

    if reference == "auto":
        reference = "labels" if usable(labels) else "truth"
    chosen = labels if reference == "labels" else truth
    if not usable(chosen):
        what = "operator labels" if reference == "labels" else "simulator truth"
        raise InferenceError(f"{path}: no {what} to compare with")
    metadata = dict(get("metadata") or {})
    metadata = {**metadata, **(metadata.get("session") or {})}  # capture nests the form
    probabilities = np.asarray(get("probabilities"), dtype=float)
    chosen = mode_indices(chosen)
    times = get("time_ns")
    times_s = None
    if times is not None and len(times) == len(chosen) and len(times):
        t = np.asarray(times, dtype=np.int64)
        times_s = (t - t[0]) * 1e-9
    finite = np.isfinite(probabilities).all(axis=1) if probabilities.ndim == 2 else None
    if finite is not None and not finite.all():
        log.warning("%s: %d frame(s) without a CNN output left out", path, (~finite).sum())
        probabilities, chosen = probabilities[finite], chosen[finite]
        times_s = times_s[finite] if times_s is not None else None
    return Trial(str(path), probabilities, chosen, metadata, times_s)


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
    method), accuracy_vs_delay (with a sweep; mean and SD over trials), decisions_<trial>
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


def _legend_below(fig, ax, ncol: int, **kwargs) -> None:
    """The legend under the axes, never over the data; a column is too narrow for one
    beside them."""
    fig.legend(
        *ax.get_legend_handles_labels(),
        loc="upper center",
        bbox_to_anchor=(0.5, 0.0),
        ncol=ncol,
        frameon=False,
        handlelength=2.2,
        columnspacing=1.0,
        **kwargs,
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
    _legend_below(fig, ax, ncol=min(4, len(methods)))
    return fig


def _plot_sweep(plt, results, sweep):
    conditions = by_condition(results)
    index = {id(r): i for i, r in enumerate(results)}
    fig, axes = plt.subplots(
        1,
        len(conditions),
        figsize=(COLUMN_IN, 2.3),
        squeeze=False,
        sharey=True,
        layout="constrained",
    )
    lowest = 100.0
    for ax, (condition, rs) in zip(axes[0], conditions.items()):
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
            ax.errorbar(
                np.asarray(sweep.delays, dtype=float) + dodge,
                mean,
                yerr=bars,
                capsize=1.5,
                elinewidth=0.6,
                color=style["line"],
                marker=style["marker"],
                markersize=3.5,
                markeredgecolor="black",
                markeredgewidth=0.4,
                linestyle=style["linestyle"],
                linewidth=1,
                label=TITLES.get(m, m),
            )
        ax.set_xticks(sweep.delays)
        ax.set_xlabel("decision delay (frames)")
        n = len(rs)
        ax.set_title(f"{condition or 'all trials'} (n = {n} trial{'s' if n != 1 else ''})")
    axes[0][0].set_ylim(_axis_floor(lowest), 100)
    axes[0][0].set_ylabel("accuracy (%), mean ± SD")
    fig.suptitle("Accuracy against decision delay")
    _legend_below(fig, axes[0][0], ncol=min(4, len(sweep.accuracy)))
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
    rows = [("reference", trial.reference)] + [
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
    ax.set_title(f"Sequential decisions: {trial.title}")
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
    fig.suptitle(f"Confusion, {where} (n = {n} trial{'s' if n != 1 else ''}): row %")
    return fig
