"""The evaluation as data: the JSON that `walkcap eval --json` prints and the text table
is made from. Accuracies as fractions, null where undefined."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import fields
from typing import Any

import numpy as np

from inference.config import FusionConfig
from inference.evaluation import errors as er
from inference.evaluation import steps as st
from inference.evaluation import transitions as tr
from inference.evaluation.metrics import (
    DelaySweep,
    PairedTests,
    by_condition,
    column_mean,
    column_sd,
    group_results,
    paired_t_tests,
    pooled_errors,
    pooled_steps,
    pooled_transitions,
    summarize,
)
from inference.evaluation.trials import TrialResult
from inference.fusion import fusion_method

# Beside window and vote_delay, the report lists each [fusion] key a method it ran takes.
_PARAMETER_KEYS = [f.name for f in fields(FusionConfig)]


def _keys_of(methods: Sequence[str]) -> set[str]:
    return {k for m in methods for k in fusion_method(m).keys}


def _num(x: float) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def _nums(d: dict) -> dict:
    return {k: _num(v) for k, v in d.items()}


def _tests_json(tests: PairedTests) -> dict:
    return {
        "trials": tests.trials,
        "min_trials": tests.min_trials,
        "too_few": tests.too_few,
        "correction": "holm",
        "tests": [
            {
                "a": t.a,
                "b": t.b,
                "n": t.n,
                "mean_difference": _num(t.mean_difference),
                "t": _num(t.t),
                "p": _num(t.p),
                "p_holm": _num(t.p_holm),
                "d_z": _num(t.d_z),
            }
            for t in tests.tests
        ],
    }


def report(
    results: Sequence[TrialResult],
    methods: Sequence[str],
    params: FusionConfig,
    sweep: DelaySweep | None = None,
    grouped: bool = False,
) -> dict:
    """{"files": [...], "mean", "sd", "delay_frames", "parameters", ...}; accuracies as
    fractions, null where undefined. grouped adds "groups" (subject x condition) and
    "conditions" (with their own paired t-tests)."""
    files = []
    for r in results:
        entry: dict[str, Any] = {"path": r.trial.path, "frames": r.trial.frames}
        labeled = r.trial.labeled_frames
        if labeled != entry["frames"]:
            entry["labeled_frames"] = labeled
        if grouped:
            entry["subject"] = r.trial.subject
            entry["condition"] = r.trial.condition
        entry["accuracy"] = _nums(r.accuracy)
        entry["references"] = r.trial.reference_names
        entry["transitions"] = {
            m: {name: tr.summary(st) for name, st in r.transitions.get(m, {}).items()}
            for m in methods
        }
        if r.steps:
            entry["steps"] = {m: st.summary(r.steps[m]) for m in methods if m in r.steps}
        if r.errors is not None:
            entry["errors"] = er.summary(r.errors)
        files.append(entry)
    summary = summarize(results, methods)
    scored = sorted({r.trial.reference_name for r in results})
    out: dict[str, Any] = {
        "files": files,
        "accuracy_reference": scored[0] if len(scored) == 1 else scored,
        "mean": _nums(summary["mean"]),
        "sd": _nums(summary["sd"]),
        "transitions": _transitions_json(results, methods),
        **_steps_json(results, methods),
        **_errors_json(results),
        "delay_frames": {m: params.delay_frames(m) for m in methods},
        "parameters": {
            "window": params.window,
            "vote_delay": params.vote_delay,
            **{
                k: getattr(params, k)
                for k in _PARAMETER_KEYS
                if k in _keys_of(methods) and k not in ("window", "vote_delay")
            },
        },
    }
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
                    **_steps_json(rs, methods),
                    **_errors_json(rs),
                }
            )
    if sweep is not None:
        with np.errstate(all="ignore"):
            out["sweep"] = {
                "delays": sweep.delays,
                "mean": {m: [_num(x) for x in column_mean(a)] for m, a in sweep.accuracy.items()},
                "sd": {m: [_num(x) for x in column_sd(a)] for m, a in sweep.accuracy.items()},
                "spurious_per_min": {
                    m: [_num(x) for x in sweep.spurious_per_min(m)] for m in sweep.spurious
                },
            }
    return out


def _transitions_json(results: Sequence[TrialResult], methods: Sequence[str]) -> dict:
    """method -> reference -> the pooled transition figures (inference.evaluation.transitions)."""
    return {
        m: {name: tr.summary(st) for name, st in pooled_transitions(results, m).items()}
        for m in methods
    }


def _steps_json(results: Sequence[TrialResult], methods: Sequence[str]) -> dict:
    """{"steps": method -> the pooled per-step figures} when any trial has steps, else {}."""
    out = {}
    for m in methods:
        stats = pooled_steps(results, m)
        if stats is not None:
            out[m] = st.summary(stats)
    return {"steps": out} if out else {}


def _errors_json(results: Sequence[TrialResult]) -> dict:
    """{"errors": the classifier's own errors pooled} (inference.evaluation.errors)."""
    shape = pooled_errors(results)
    return {"errors": er.summary(shape)} if shape is not None else {}
