"""A trained network saved with its metadata: the preprocessing it expects, the data and
split it saw, the settings and history, the test sessions' metrics."""

from __future__ import annotations

from dataclasses import asdict

import torch

from inference.model import save_model
from inference.training.loop import TrainResult
from inference.training.settings import TrainSettings


def training_metadata(
    result: TrainResult,
    settings: TrainSettings,
    preprocess: dict,
    sources: list[str],
    extra: dict | None = None,
) -> dict:
    """The metadata file's content beyond what save_model adds."""
    seeds = sorted({s for part in ("train", "validation") for s in result.split[part]})
    return {
        "preprocess": preprocess,
        "data": {**result.data, "sources": sources, "sessions_seen_in_training": seeds},
        "split": result.split,
        "training": {
            **asdict(settings),
            "best_epoch": result.best_epoch,
            "epochs_run": len(result.history),
            "stopped_early": result.stopped_early,
            "seconds": round(result.seconds, 1),
            "history": result.history,
            "torch": torch.__version__,
        },
        "metrics": {
            "test": {k: v.to_dict() for k, v in result.test_metrics.items()},
            **(extra or {}),
        },
    }


def save_result(
    result: TrainResult,
    path: str,
    settings: TrainSettings,
    preprocess: dict,
    sources: list[str],
    extra: dict | None = None,
):
    return save_model(
        result.net, path, training_metadata(result, settings, preprocess, sources, extra)
    )
