"""Training the terrain classifier, and measuring it: `data` (the split, balancing,
augmentation), `loop` (`train`), `metrics` (per-frame quality), `checkpoint` (the saved
model and its metadata), `settings` (`TrainSettings`).

- Sessions are split into train / validation / test by session (stratified by preset), so
  frames of one walk never sit on both sides.
- Classes are balanced by sampling: each epoch draws frames with probability
  proportional to their class's frequency to the power -balance_power (level ground
  dominates every walk; 1 is full balance, the default 0.3 part of the way).
- Augmentation imitates the sensor, on the occupied cells of the binary image: a small
  rotation of the profile (IMU pitch error, mounting error), a small scale (depth scale,
  camera height), missing returns, the stray returns under a surface missing (the shift
  then lands on the surface itself), a stray cell; then the authors' shift of the minimum
  to one cell, as the preprocessing does. No left-right flips: they reverse up and down.
- Mirrored ascents: a share of the up-stairs and up-ramp frames is mirrored in height and
  trained as down stairs and down ramp. The simulator shows a descent as its geometry
  does, treads stepping down with gaps where the nosings hide the risers; a person, and
  the authors' textbook set, read a staircase drawn with its risers going down as down
  stairs too (and the camera's mixed pixels at a nosing draw part of one). A mirrored
  ascent is that staircase.
- Adam with cross-entropy; the learning rate halves when the validation loss stalls, and
  training stops after `patience` epochs without improvement, keeping the best weights.
- Deterministic for a seed on one machine (one process, seeded generators, deterministic
  algorithms); CPU by default, the GPU when there is one (device "auto").
- Distributed when torch.distributed is set up (capture.corpus.cluster starts it): the model in
  DistributedDataParallel, each epoch's frames and each batch split between the processes
  (the batch size is the total), validation split and summed, so every process takes the
  same early-stopping and learning-rate steps.

The package loads its parts on first use: `TrainSettings` (in `settings`) is plain values,
and `walkcap`'s parser reads its defaults on every command without loading torch.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from inference.training.checkpoint import save_result, training_metadata
    from inference.training.data import augment_image, split_by_session
    from inference.training.loop import TrainResult, keep_freed_memory, train
    from inference.training.metrics import (
        GroupMetrics,
        evaluate_sessions,
        format_metrics,
        group_metrics,
    )
    from inference.training.settings import TrainSettings

_HOMES = {  # name -> the module of this package that defines it
    "GroupMetrics": "metrics",
    "TrainResult": "loop",
    "TrainSettings": "settings",
    "augment_image": "data",
    "evaluate_sessions": "metrics",
    "format_metrics": "metrics",
    "group_metrics": "metrics",
    "keep_freed_memory": "loop",
    "save_result": "checkpoint",
    "split_by_session": "data",
    "train": "loop",
    "training_metadata": "checkpoint",
}

__all__ = [
    "GroupMetrics",
    "TrainResult",
    "TrainSettings",
    "augment_image",
    "evaluate_sessions",
    "format_metrics",
    "group_metrics",
    "keep_freed_memory",
    "save_result",
    "split_by_session",
    "train",
    "training_metadata",
]


def __getattr__(name: str):
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{home}"), name)
    globals()[name] = value  # found directly from now on
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_HOMES))
