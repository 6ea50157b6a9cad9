"""A training run's settings: plain values, no torch, so that `walkcap`'s parser can show
them as defaults without loading the training stack."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class TrainSettings:
    epochs: int = 12
    batch_size: int = 64
    lr: float = 1e-3
    weight_decay: float = 1e-4
    patience: int = 3  # epochs without a better validation loss before stopping
    val_fraction: float = 0.15  # of the sessions
    test_fraction: float = 0.15
    seed: int = 0
    hidden: int = 32  # inference.model.DEFAULT_HIDDEN, written out: that module loads torch
    device: str = "auto"
    augment: bool = True
    balance: bool = True
    # Sampling weight of a frame: class frequency ** -balance_power. 1 draws every class
    # equally often (softmax ~ likelihood); lower keeps part of level ground's prior. 0.3
    # scores higher than 0.5 on held-out sessions, per frame and after HMM fusion, at some
    # cost in down-stairs recall.
    balance_power: float = 0.3
    augment_probability: float = 0.5  # share of training frames that are augmented
    mirror_probability: float = 0.2  # share of US and UR frames mirrored into DS and DR
    bf16: bool = True  # bfloat16 autocast on CPUs with native support (about 1.7x faster)
    samples_per_epoch: int = 0  # frames drawn per epoch; 0: as many as the training set
    max_steps: int = 0  # stop after this many optimiser steps in total (0: no limit)
    threads: int = 0  # torch intra-op threads; 0: leave as is
    max_seconds: float = 0.0  # wall-clock budget; the epoch running out of it ends early
