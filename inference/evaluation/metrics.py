"""Running the fusion methods over trials and scoring them the way the paper does:
per-frame accuracy per trial, mean +- SD across trials, paired t-tests (Holm-corrected,
with Cohen's d_z), accuracy and spurious switches against delay, confusion matrices.

Decisions always come from the streaming objects of `inference.fusion`, pushed frame by
frame and flushed at the end (`run_offline`): offline results are the live ones.
Accuracy is the fraction of frames whose final decision equals the reference, over the
frames that have a reference (-1 = none); the mean over trials is the mean of the trials'
accuracies, as in the paper (not pooled over frames); SD uses n-1. Accuracy is scored
against the trial's `reference` (`terrain` unless asked otherwise); the transition
metrics (`inference.evaluation.transitions`) against each reference the trial has.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from inference.config import FusionConfig
from inference.errors import InferenceError
from inference.evaluation import errors as er
from inference.evaluation import steps as st
from inference.evaluation import transitions as tr
from inference.evaluation.trials import FusionRun, Trial, TrialResult
from inference.fusion import METHOD_TABLE, Fusion, Voter, fusion_method
from inference.fusion_design import N_MODES, estimate_transition

PAPER_METHODS = tuple(m.name for m in METHOD_TABLE if m.paper)
TITLES = {m.name: m.title for m in METHOD_TABLE}


# A paired t-test on fewer trials than this is reported as too few, not tested: with 2-4
# pairs the p-value rests on a variance estimated from 1-3 degrees of freedom.
MIN_TRIALS_FOR_TEST = 5


@dataclass
class PairedTest:
    """One pair of methods over the same trials: a - b. NaN where undefined (identical
    results: t and d_z NaN, p 1; a constant non-zero difference: no variance to test)."""

    a: str
    b: str
    n: int
    t: float
    p: float
    p_holm: float = math.nan  # p adjusted by Holm over every pair of the same family
    d_z: float = math.nan  # Cohen's d_z: mean difference / SD of the differences
    mean_difference: float = math.nan  # accuracy of a minus accuracy of b, mean over trials


@dataclass
class PairedTests:
    """Every pair of methods over one set of trials, Holm-corrected as one family; empty
    `tests` when there are fewer than `min_trials` trials."""

    trials: int
    min_trials: int
    tests: list[PairedTest]

    @property
    def too_few(self) -> bool:
        return self.trials < self.min_trials


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


class FrameOutputs:
    """What a fusion's outputs (push and flush) say of each of `n` frames: its decision,
    vote and posterior (-1, nan: none)."""

    def __init__(self, n: int) -> None:
        self.decisions = np.full(n, -1)
        self.voted = np.full(n, -1)
        self.posteriors = np.full((n, N_MODES), np.nan)

    def add(self, out) -> None:
        """One output (None: a push that decided nothing yet)."""
        if out is None:
            return
        if out.frame is not None:
            self.decisions[out.frame] = out.decision
        if out.posterior_frame is not None:
            self.posteriors[out.posterior_frame] = out.probabilities
        if out.voted_frame is not None:
            self.voted[out.voted_frame] = out.voted


def run_offline(
    fusion: Fusion,
    probabilities: np.ndarray,
    elevation_deg: np.ndarray | None = None,
    geometry: np.ndarray | None = None,
    ground_ahead: np.ndarray | None = None,
    gait_events: list[tuple[float, str]] | None = None,
    times_s: np.ndarray | None = None,
) -> FusionRun:
    """Push every frame through a fresh streaming object, then flush: the live decisions.

    A frame whose probabilities are not finite (a broken classifier) is pushed as uniform,
    carrying no evidence, and left undecided (-1): it is never scored as right. A method
    that takes the camera's elevation (`takes_elevation`) gets each frame's,
    `elevation_deg` (NaN for each when not given, but a method with gait cues, `uses_gait`,
    needs it); one
    with the geometry cue (`uses_geometry`) sees each frame's `geometry` and `ground_ahead`
    (-1 where not given) after its push, as the live pipeline shows it the frame's terrain
    features; one that acts at steps (`uses_steps`) gets each of `gait_events` ((time s,
    event), the detector's) with `see_gait` before the first frame at or after its time
    (`times_s`), as the live pipeline hands it each event as it is detected."""
    e = np.array(probabilities, dtype=float)
    unusable = ~np.all(np.isfinite(e), axis=1) if e.ndim == 2 else np.zeros(len(e), bool)
    e[unusable] = 1.0 / N_MODES
    n = len(e)
    by_frame = FrameOutputs(n)
    decisions, voted, posteriors = by_frame.decisions, by_frame.voted, by_frame.posteriors
    collect = by_frame.add
    fusion.reset()

    elevations: list[float] = []
    if getattr(fusion, "takes_elevation", False):
        if elevation_deg is None and getattr(fusion, "uses_gait", False):
            raise InferenceError(
                f"{fusion.method} needs the camera's orientation at each frame (recordings)"
            )
        elevations = (
            [math.nan] * n
            if elevation_deg is None
            else np.asarray(elevation_deg, dtype=float).tolist()
        )
        if len(elevations) != n:
            raise InferenceError(f"{n} frames but {len(elevations)} camera elevations")
    if getattr(fusion, "uses_gait", False):
        for row, elevation in zip(e, elevations):
            collect(fusion.push(row, elevation))
    elif getattr(fusion, "uses_steps", False):
        if gait_events is None:
            raise InferenceError(
                f"{fusion.method} needs the gait events of the instrumented leg (/gait in "
                "recordings, the heel_contact column in score files)"
            )
        t = tr.frame_times(n, times_s).tolist()
        events = sorted(gait_events)
        k = 0
        for i, (row, time) in enumerate(zip(e, t)):
            while k < len(events) and events[k][0] <= time:
                fusion.see_gait(events[k][1])
                k += 1
            collect(fusion.push(row, elevations[i]) if elevations else fusion.push(row))
    elif getattr(fusion, "uses_geometry", False):
        if geometry is None:
            raise InferenceError(
                f"{fusion.method} needs the terrain features of each frame (recordings)"
            )
        shown = np.asarray(geometry, dtype=int).tolist()
        ahead = [-1] * n if ground_ahead is None else np.asarray(ground_ahead, dtype=int).tolist()
        for row, mode, slope_mode in zip(e, shown, ahead):
            collect(fusion.push(row))
            fusion.see_geometry(mode, slope_mode)
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


def _per_trial(params: FusionConfig | Sequence[FusionConfig] | None, n: int):
    """One parameter set per trial: the same for every trial, or one each."""
    if params is None:
        params = FusionConfig()
    if isinstance(params, FusionConfig):
        return [params] * n
    if len(params) != n:
        raise ValueError("one FusionConfig per trial")
    return list(params)


def evaluate_trial(
    trial: Trial,
    methods: Sequence[str] = PAPER_METHODS,
    params: FusionConfig | None = None,
    *,
    keep_runs: bool = True,
) -> TrialResult:
    """Each method over the trial: its accuracy, switches and per-step figures, and the
    classifier's own errors. `keep_runs` False: each method's per-frame run is dropped
    once its figures are taken (runs empty), so that a long trial holds one run at a
    time; plots, the delay sweep and the confusion matrices need the runs."""
    if not (trial.reference >= 0).any():
        raise InferenceError(f"{trial.path}: no frame has a reference mode")
    params = params or FusionConfig()
    result = TrialResult(trial, {}, {}, {}, {}, trial_errors(trial))
    for m in methods:
        try:
            run = run_trial(params.make(m), trial)
        except InferenceError as e:
            raise InferenceError(f"{trial.path}: {e}") from None
        result.accuracy[m] = accuracy(run.final, trial.reference)
        delay = params.delay_frames(m)
        result.transitions[m] = trial_transitions(trial, run.final, delay)
        if trial.steps is not None:
            result.steps[m] = trial_steps(trial, run.final, delay)
        if keep_runs:
            result.runs[m] = run
    return result


def trial_errors(trial: Trial) -> er.ErrorShape:
    """The shape of the classifier's own errors (each frame's argmax) against the trial's
    reference, split by swing and stance where the trial has its steps."""
    t = tr.frame_times(trial.frames, trial.times_s)
    steps = trial.steps
    return er.error_shape(
        decisions_of(trial.probabilities),
        trial.reference,
        trial.probabilities,
        t,
        tr.duration_minutes(t),
        () if steps is None else steps.heel_contacts_s,
        () if steps is None else steps.toe_offs_s,
    )


def pooled_errors(results: Sequence[TrialResult]) -> er.ErrorShape | None:
    shapes = [r.errors for r in results if r.errors is not None]
    return er.pooled(shapes) if shapes else None


def run_trial(fusion: Fusion, trial: Trial) -> FusionRun:
    """`run_offline` over a trial, with every cue it has."""
    return run_offline(
        fusion,
        trial.probabilities,
        trial.elevation_deg,
        trial.geometry,
        trial.ground_ahead,
        trial.gait_events,
        trial.times_s,
    )


def trial_steps(trial: Trial, final: np.ndarray, delay_frames: int) -> st.StepStats:
    """A decision sequence's per-step figures at the trial's steps."""
    t = tr.frame_times(trial.frames, trial.times_s)
    return st.step_stats(t, final, delay_frames, trial.steps, tr.duration_minutes(t))


def pooled_steps(results: Sequence[TrialResult], method: str) -> st.StepStats | None:
    """The trials' per-step figures pooled (None: no trial has steps)."""
    stats = [r.steps[method] for r in results if method in r.steps]
    return st.pooled(stats) if stats else None


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
    params: FusionConfig | Sequence[FusionConfig] | None = None,
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


def paired_t_test(x: Sequence[float], y: Sequence[float], a: str = "", b: str = "") -> PairedTest:
    """The paired t-test of x - y (as scipy.stats.ttest_rel), its d_z and mean difference.
    Computed from the differences directly: scipy warns of catastrophic cancellation when
    they are nearly constant, and the answer there is the one below."""
    from scipy import stats

    d = np.asarray(x, dtype=float) - np.asarray(y, dtype=float)
    n = len(d)
    if n < 2:
        return PairedTest(a, b, n, math.nan, math.nan)
    mean = float(d.mean())
    sd = float(d.std(ddof=1))
    if not np.any(d != 0):
        return PairedTest(a, b, n, math.nan, 1.0, d_z=math.nan, mean_difference=0.0)
    if sd <= 1e-12 * abs(mean):  # a constant difference: no variance to test against
        return PairedTest(a, b, n, math.nan, math.nan, mean_difference=mean)
    t = mean / (sd / math.sqrt(n))
    p = float(2 * stats.t.sf(abs(t), n - 1))
    return PairedTest(a, b, n, t, p, d_z=mean / sd, mean_difference=mean)


def holm(pvalues: Sequence[float]) -> list[float]:
    """Holm's step-down adjustment of a family of p-values (NaN ones are not counted)."""
    p = np.asarray(pvalues, dtype=float)
    out = np.full(len(p), np.nan)
    idx = [i for i in np.argsort(p, kind="stable") if math.isfinite(p[i])]
    m = len(idx)
    running = 0.0
    for rank, i in enumerate(idx):
        running = max(running, min(1.0, (m - rank) * p[i]))
        out[i] = running
    return [float(v) for v in out]


def paired_t_tests(
    results: Sequence[TrialResult],
    methods: Sequence[str],
    min_trials: int = MIN_TRIALS_FOR_TEST,
) -> PairedTests:
    """Paired t-tests between every two methods over the same trials, Holm-corrected
    together; none below `min_trials` trials."""
    n = len(results)
    if n < min_trials:
        return PairedTests(n, min_trials, [])
    tests = []
    for i, a in enumerate(methods):
        for b in methods[i + 1 :]:
            x = [r.accuracy[a] for r in results]
            y = [r.accuracy[b] for r in results]
            tests.append(paired_t_test(x, y, a, b))
    for test, adjusted in zip(tests, holm([t.p for t in tests])):
        test.p_holm = adjusted
    return PairedTests(n, min_trials, tests)


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
    params: FusionConfig | Sequence[FusionConfig] | None = None,
) -> DelaySweep:
    """Accuracy against the number of delayed frames D = 0..max_delay (the paper's trade-off).

    A method that votes (`votes_on`): l_v = D minus its base's delay (the HMM adds one
    frame); one that takes a lag: lag = D. Methods without a delay parameter keep their accuracy for
    every D at or above their own delay; NaN below it. Beside accuracy, the spurious
    switches (inference.evaluation.transitions) against the same reference.
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
                stages[method] = run_trial(p.make(method), trial)
            return stages[method]

        for m in methods:
            spec = fusion_method(m)
            if spec.votes_on is not None:  # its voting window: the delay beyond its base's
                base = p.delay_frames(spec.votes_on)
                for d in delays[base:]:
                    score(m, d, vote_offline(stage(spec.votes_on).decisions, d - base), d)
            elif "lag" in spec.keys:  # its lag: the delay
                for d in delays:
                    score(
                        m, d, run_offline(replace(p, lag=d).make(m), trial.probabilities).final, d
                    )
            else:  # no delay parameter: the same decisions at every delay from their own
                own = p.delay_frames(m)
                if own <= max_delay:
                    score(m, own, stage(m).final, own)
                    acc[m][i, own:] = acc[m][i, own]
                    spurious[m][i, own:] = spurious[m][i, own]
    return DelaySweep(delays, acc, spurious, minutes)


def column_mean(a: np.ndarray) -> np.ndarray:
    """The mean of each column (a delay of a sweep); NaN where a trial has none."""
    return np.array([np.mean(c) if not np.isnan(c).any() else np.nan for c in a.T])


def column_sd(a: np.ndarray) -> np.ndarray:
    """The sample SD of each column; NaN where a trial has none or there is one trial."""
    return np.array(
        [np.std(c, ddof=1) if len(c) > 1 and not np.isnan(c).any() else np.nan for c in a.T]
    )
