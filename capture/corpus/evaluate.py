"""`walkcap eval recordings` over a study: one recording read and evaluated at a time."""

from __future__ import annotations


def evaluate_recording(path, reference: str, name: str, methods, params):
    """One recording's evaluation (inference.evaluation.evaluate_trial) as its summarized
    result: a task of a corpus job (capture.corpus.jobs), so that a study of hundreds of
    long trials holds one trial's frames (and one method's run) at a time, and each trial's
    figures."""
    from capture.corpus.trials import read_evaluation_trial
    from inference.evaluation.metrics import evaluate_trial

    trial = read_evaluation_trial(path, reference, name)
    return evaluate_trial(trial, methods, params, keep_runs=False).summarized()
