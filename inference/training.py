"""Training the terrain classifier, and measuring it.

- Sessions are split into train / validation / test by session (stratified by preset), so
  frames of one walk never sit on both sides.
- Classes are balanced by sampling: each epoch draws frames with probability
  proportional to their class's frequency to the power -balance_power (level ground
  dominates every walk; 1 is full balance, the default 0.3 part of the way).
- Augmentation imitates the sensor, on the occupied cells of the binary image: a small
  rotation of the profile (IMU pitch error, mounting error), a small scale (depth scale,
  camera height), missing returns, a stray cell; then the authors' shift of the minimum to
  one cell, as the preprocessing does. No left-right flips: they reverse up and down.
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
"""

from __future__ import annotations

import copy
import ctypes
import logging
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import numpy as np
import torch
import torch.nn.functional as F

from devices.frames import MODES
from inference.dataset import LabeledSession, summarize
from inference.errors import InferenceError
from inference.model import (
    DEFAULT_HIDDEN,
    Classifier,
    TerrainCNN,
    choose_device,
    images_to_tensor,
    save_model,
)

log = logging.getLogger(__name__)


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
    hidden: int = DEFAULT_HIDDEN
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


@dataclass
class GroupMetrics:
    """Per-frame quality of one group of frames (all, indoor, outdoor)."""

    frames: int
    accuracy: float  # fraction of frames right
    balanced_accuracy: float  # mean of the per-class accuracies present
    per_class: dict  # mode -> accuracy (recall), None when the class is absent
    confusion: list  # 5 x 5 counts, rows true mode, columns predicted mode
    # Where the errors fall, when the sessions carry the simulator's truth (see
    # error_breakdown); None otherwise.
    breakdown: dict | None = None
    # Each session's own accuracy (evaluate_sessions): how far one walk's figure strays.
    session_accuracy: list | None = None

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class TrainResult:
    net: TerrainCNN
    history: list = field(default_factory=list)  # per epoch: losses, accuracies, lr
    best_epoch: int = 0
    split: dict = field(default_factory=dict)  # names of the sessions in each part
    test_metrics: dict = field(default_factory=dict)  # group -> GroupMetrics
    data: dict = field(default_factory=dict)  # summaries of each part
    seconds: float = 0.0
    stopped_early: bool = False


# ---- split -------------------------------------------------------------------------------


def split_by_session(
    sessions: list[LabeledSession], val_fraction: float, test_fraction: float, seed: int
) -> tuple[list[LabeledSession], list[LabeledSession], list[LabeledSession]]:
    """Train, validation and test sessions; whole sessions, stratified by preset."""
    if len(sessions) < 3:
        raise InferenceError(
            f"need at least 3 sessions to split into train, validation "
            f"and test, got {len(sessions)}"
        )
    names = [s.name for s in sessions]
    if len(set(names)) != len(names):
        raise InferenceError("two sessions have the same name; a walk must not be split")
    rng = np.random.default_rng(seed)
    groups: dict[str, list[int]] = {}
    for i, s in enumerate(sorted(sessions, key=lambda s: s.name)):
        groups.setdefault(s.preset, []).append(i)
    ordered = sorted(sessions, key=lambda s: s.name)
    train, val, test = [], [], []
    for preset in sorted(groups):
        idx = list(rng.permutation(groups[preset]))
        n = len(idx)
        n_test = int(round(n * test_fraction)) if test_fraction > 0 else 0
        n_val = int(round(n * val_fraction)) if val_fraction > 0 else 0
        if n >= 3:
            n_test = max(n_test, 1 if test_fraction > 0 else 0)
            n_val = max(n_val, 1 if val_fraction > 0 else 0)
        n_test = min(n_test, max(n - 1, 0))
        n_val = min(n_val, max(n - 1 - n_test, 0))
        test += [ordered[i] for i in idx[:n_test]]
        val += [ordered[i] for i in idx[n_test : n_test + n_val]]
        train += [ordered[i] for i in idx[n_test + n_val :]]
    if not val and val_fraction > 0:  # tiny presets: borrow one training session
        val.append(train.pop())
    if not train:
        raise InferenceError("no sessions left for training after the split")
    return train, val, test


# ---- augmentation ------------------------------------------------------------------------


# An ascent mirrored in height is the descent of the same shape (module docstring).
MIRRORED = {MODES.index("US"): MODES.index("DS"), MODES.index("UR"): MODES.index("DR")}


def augment_image(
    image: np.ndarray,
    rng: np.random.Generator,
    tilt_deg: float = 1.0,
    scale: float = 0.04,
    dropout: float = 0.15,
    mirror: bool = False,
) -> np.ndarray:
    """A plausible other view of the same terrain (see the module docstring); `mirror`:
    of the terrain mirrored in height (an ascent's image becomes a descent's).

    The tilt is small: synthetic sessions already carry the IMU's and the mounting's
    errors (about 1.4 degrees of pitch together), and 2 degrees more turns 5-6 degree
    up ramps into level ground (their images then show 3.4-4.2 degrees of slope).

    Image convention (inference.preprocess): col = forward cells (0 nearest),
    row 0 = highest; the profile's minimum sits in column 1 and the row above the last.
    """
    grid = image.shape[0]
    rows, cols = np.nonzero(image)
    if len(rows) < 3:
        return image
    # Two sub-cell samples per occupied cell so that rotation leaves no holes.
    x = np.repeat(cols, 2) + rng.random(2 * len(cols))
    z = np.repeat(grid - 1 - rows, 2) + rng.random(2 * len(rows))
    if mirror:
        z = -z
    angle = np.radians(rng.normal(0.0, tilt_deg))
    s = 1.0 + rng.uniform(-scale, scale)
    c, sn = math.cos(angle) * s, math.sin(angle) * s
    x, z = c * x - sn * z, sn * x + c * z
    keep = rng.random(len(x)) >= rng.uniform(0.0, dropout)  # missing returns
    if keep.sum() < 3:
        return image
    x, z = x[keep], z[keep]
    col = (x - x.min()).astype(np.int64) + 1  # the authors' shift: minimum in cell 1
    up = (z - z.min()).astype(np.int64) + 1
    ok = (col < grid) & (up < grid)
    out = np.zeros_like(image)
    out[grid - 1 - up[ok], col[ok]] = 1
    if rng.random() < 0.2:  # a stray cell the outlier filter let through
        r, q = rng.integers(0, grid, 2)
        out[r, q] = 1
    return out


# ---- metrics ---------------------------------------------------------------------------------


def group_metrics(labels: np.ndarray, predictions: np.ndarray) -> GroupMetrics:
    from inference.evaluation.metrics import confusion_matrix

    labels = np.asarray(labels)
    cm = confusion_matrix(np.asarray(predictions), labels)
    # every labelled frame counts, an undecided one (-1: no finite output) as wrong
    return confusion_metrics(
        cm, np.bincount(labels[labels >= 0], minlength=len(MODES))[: len(MODES)]
    )


def confusion_metrics(cm: np.ndarray, totals: np.ndarray | None = None) -> GroupMetrics:
    """Metrics from a confusion matrix; `totals`: frames per true mode (default: its rows)."""
    totals = cm.sum(axis=1) if totals is None else totals
    per_class = {
        m: (float(cm[i, i] / totals[i]) if totals[i] else None) for i, m in enumerate(MODES)
    }
    present = [v for v in per_class.values() if v is not None]
    frames = int(totals.sum())
    return GroupMetrics(
        frames=frames,
        accuracy=float(np.trace(cm) / frames) if frames else float("nan"),
        balanced_accuracy=float(np.mean(present)) if present else float("nan"),
        per_class=per_class,
        confusion=cm.tolist(),
    )


# Where a classifier's errors fall, on synthesized sessions (their simulator truth says which
# mode the walker itself is in and which frames are error images). The truth is what each
# image shows, so near a change it leads the walker's own mode (the camera looks ahead) or,
# on a thigh swung back, lags it; the "locomotion oracle" (the walker's mode as the answer)
# is how far that is from answering the image. Groups, first match wins:
BREAKDOWN_GROUPS = (
    "error image",
    "near a mode change, the walker is in another mode",
    "near a mode change, the walker is in the mode",
    "elsewhere",
)
NEAR_CHANGE_S = 1.0  # "near a mode change": within this long of one


def frame_groups(
    labels: np.ndarray, locomotion_modes: np.ndarray, errors: np.ndarray, near_frames: int
) -> np.ndarray:
    """Each frame's index in BREAKDOWN_GROUPS; one walk's labelled frames, in order."""
    labels = np.asarray(labels)
    n = len(labels)
    changes = np.flatnonzero(np.diff(labels)) + 1  # first frame of each new mode
    near = np.zeros(n, bool)
    if len(changes):
        i = np.arange(n)
        after = np.clip(np.searchsorted(changes, i), 0, len(changes) - 1)
        before = np.clip(after - 1, 0, len(changes) - 1)
        distance = np.minimum(np.abs(i - changes[after]), np.abs(i - changes[before]))
        near = distance < near_frames
    shows = np.asarray(locomotion_modes) == np.asarray(MODES)[labels]
    return np.where(np.asarray(errors) != "", 0, np.where(near, np.where(shows, 2, 1), 3))


def error_breakdown(
    groups: np.ndarray, right: np.ndarray, walker_right: np.ndarray, near_frames: int
) -> dict:
    """Share of frames, accuracy and points of accuracy lost per group; the locomotion oracle."""
    total = len(groups)
    parts = {}
    for g, name in enumerate(BREAKDOWN_GROUPS):
        mask = groups == g
        n = int(mask.sum())
        parts[name] = {
            "frames": n,
            "accuracy": float(right[mask].mean()) if n else None,
            "points_lost": float((mask & ~right).sum() / total * 100),
        }
    return {
        "near_frames": near_frames,
        "locomotion_accuracy": float(walker_right.mean()),
        "groups": parts,
    }


def evaluate_sessions(
    classifier: Classifier, sessions: list[LabeledSession]
) -> dict[str, GroupMetrics]:
    """Per-frame quality, all frames and per preset ("all", "indoor", "outdoor", ...);
    with the error breakdown when every session carries the simulator's truth."""
    from inference.evaluation.metrics import decisions_of

    labels: dict[str, list[np.ndarray]] = {"all": []}
    preds: dict[str, list[np.ndarray]] = {"all": []}
    per_session: dict[str, list[float]] = {"all": []}
    groups: dict[str, list[np.ndarray]] = {"all": []}
    views: dict[str, list[np.ndarray]] = {"all": []}
    near_frames = 0
    with_truth = all(s.locomotion_modes is not None and s.errors is not None for s in sessions)
    for s in sessions:
        s = s.labelled()
        if not len(s):
            continue
        p = decisions_of(classifier.predict_batch(s.images))
        for key in ("all", s.preset or "unknown"):
            labels.setdefault(key, []).append(s.labels)
            preds.setdefault(key, []).append(p)
            per_session.setdefault(key, []).append(float(np.mean(p == s.labels)))
        if with_truth:
            near_frames = max(1, int(round(NEAR_CHANGE_S * s.meta.get("fps", 15))))
            g = frame_groups(s.labels, s.locomotion_modes, s.errors, near_frames)
            walker_right = s.locomotion_modes == np.asarray(MODES)[s.labels]
            for key in ("all", s.preset or "unknown"):
                groups.setdefault(key, []).append(g)
                views.setdefault(key, []).append(walker_right)
    if not labels["all"]:
        raise InferenceError("no labelled frames to evaluate")
    out = {}
    for k in labels:
        y, p = np.concatenate(labels[k]), np.concatenate(preds[k])
        out[k] = group_metrics(y, p)
        out[k].session_accuracy = per_session[k]
        if with_truth:
            out[k].breakdown = error_breakdown(
                np.concatenate(groups[k]), p == y, np.concatenate(views[k]), near_frames
            )
    return out


def format_metrics(metrics: dict[str, GroupMetrics], title: str = "") -> str:
    """A readable report: accuracy per group, per class, and the confusion matrices."""
    from inference.evaluation.metrics import mean_sd

    lines = [title] if title else []
    for group, m in metrics.items():
        lines.append(
            f"{group}: {m.accuracy * 100:.2f} % of {m.frames} frames "
            f"(balanced {m.balanced_accuracy * 100:.2f} %)"
        )
        if m.session_accuracy and len(m.session_accuracy) > 1:
            mean, sd = mean_sd(m.session_accuracy)
            lines.append(
                f"  per session: mean {mean * 100:.2f} %, SD {sd * 100:.2f} points, "
                f"{min(m.session_accuracy) * 100:.1f}-"
                f"{max(m.session_accuracy) * 100:.1f} % over "
                f"{len(m.session_accuracy)} sessions"
            )
        lines.append(
            "  per class: "
            + "  ".join(
                f"{k} {'-' if v is None else f'{v * 100:.1f}'}" for k, v in m.per_class.items()
            )
        )
        lines.append("  confusion (rows true, columns predicted):")
        lines.append("        " + "".join(f"{k:>7}" for k in MODES))
        for k, row in zip(MODES, m.confusion):
            lines.append(f"    {k:>4}" + "".join(f"{v:>7}" for v in row))
        if m.breakdown:
            lines += _format_breakdown(m.breakdown, m.frames)
    return "\n".join(lines)


def _format_breakdown(b: dict, frames: int) -> list[str]:
    lines = [
        f"  where the errors are (near: within {b['near_frames']} frames of a change of "
        f"the true mode):"
    ]
    for name, part in b["groups"].items():
        right = "-" if part["accuracy"] is None else f"{part['accuracy'] * 100:.1f} %"
        lines.append(
            f"    {name:<48} {part['frames'] / frames * 100:5.1f} % of frames, "
            f"{right:>7} right, {part['points_lost']:.2f} points lost"
        )
    lines.append(
        f"  locomotion oracle (answering the mode the walker is in): "
        f"{b['locomotion_accuracy'] * 100:.2f} %"
    )
    return lines


# ---- training --------------------------------------------------------------------------------


def _stack(sessions: list[LabeledSession]) -> tuple[np.ndarray, np.ndarray]:
    parts = [s.labelled() for s in sessions]
    parts = [p for p in parts if len(p)]
    if not parts:
        return np.zeros((0, 100, 100), np.uint8), np.zeros(0, np.int64)
    return (
        np.concatenate([p.images for p in parts]),
        np.concatenate([p.labels for p in parts]).astype(np.int64),
    )


def _epoch_indices(
    labels: np.ndarray, count: int, balance: bool, rng: np.random.Generator, power: float = 1.0
) -> np.ndarray:
    if not balance or power == 0:
        return (
            rng.permutation(len(labels))[:count]
            if count <= len(labels)
            else rng.integers(0, len(labels), count)
        )
    freq = np.bincount(labels, minlength=len(MODES)).astype(np.float64)
    weights = freq[labels] ** -power
    return rng.choice(len(labels), size=count, replace=True, p=weights / weights.sum())


def _batches(
    images: np.ndarray,
    labels: np.ndarray,
    order: np.ndarray,
    batch_size: int,
    augment: float,
    rng: np.random.Generator,
    mirror: float = 0.0,
):
    """Batches in `order`; each frame augmented with probability `augment`, each ascent
    mirrored into a descent with probability `mirror` (MIRRORED)."""
    for i in range(0, len(order), batch_size):
        idx = order[i : i + batch_size]
        batch, target = images[idx], labels[idx]
        if augment > 0 or mirror > 0:
            target = target.copy()
            out = []
            for k, img in enumerate(batch):
                if mirror > 0 and int(target[k]) in MIRRORED and rng.random() < mirror:
                    target[k] = MIRRORED[int(target[k])]
                    out.append(augment_image(img, rng, mirror=True))
                elif augment > 0 and rng.random() < augment:
                    out.append(augment_image(img, rng))
                else:
                    out.append(img)
            batch = np.stack(out)
        yield images_to_tensor(batch), torch.from_numpy(target)


@torch.no_grad()
def _validate(
    net: TerrainCNN,
    images: np.ndarray,
    labels: np.ndarray,
    device: torch.device,
    power: float = 1.0,
    batch_size: int = 256,
    world: _World | None = None,
) -> tuple[float, float, float]:
    """Mean loss with the class weights the balanced sampling gives (frequency ** -power),
    accuracy and balanced accuracy. Distributed, each process takes every world.size-th
    frame and the sums are added up."""
    from inference.evaluation.metrics import confusion_matrix

    net.eval()
    if not len(labels):
        return float("nan"), float("nan"), float("nan")
    freq = np.bincount(labels, minlength=len(MODES)).astype(np.float64)
    weights = torch.tensor(
        np.where(freq > 0, np.maximum(freq, 1) ** -power, 0.0), dtype=torch.float32, device=device
    )
    if world is not None:
        images, labels = images[world.rank :: world.size], labels[world.rank :: world.size]
    loss_sum, weight_sum, preds = 0.0, 0.0, []
    for i in range(0, len(labels), batch_size):
        x = images_to_tensor(images[i : i + batch_size]).to(device)
        y = torch.from_numpy(labels[i : i + batch_size]).to(device)
        scores = net(x)
        loss_sum += float(F.cross_entropy(scores, y, weight=weights, reduction="sum"))
        weight_sum += float(weights[y].sum())
        preds.append(scores.argmax(1).cpu().numpy())
    cm = confusion_matrix(np.concatenate(preds) if preds else np.zeros(0, int), labels)
    if world is not None:
        loss_sum, weight_sum, *counts = world.sum([loss_sum, weight_sum, *cm.ravel()])
        cm = np.rint(np.array(counts)).astype(int).reshape(cm.shape)
    m = confusion_metrics(cm)
    return loss_sum / weight_sum, m.accuracy, m.balanced_accuracy


@dataclass(frozen=True)
class _World:
    """This process's place in a torch.distributed group."""

    rank: int
    size: int

    @staticmethod
    def current() -> _World | None:
        import torch.distributed as dist

        if dist.is_available() and dist.is_initialized() and dist.get_world_size() > 1:
            return _World(dist.get_rank(), dist.get_world_size())
        return None

    def sum(self, values: list[float]) -> list[float]:
        import torch.distributed as dist

        t = torch.tensor(values, dtype=torch.float64)
        dist.all_reduce(t)
        return t.tolist()

    def any(self, flag: bool) -> bool:
        return self.sum([float(flag)])[0] > 0


def _native_bf16() -> bool:
    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):
        return False


@torch.no_grad()
def _warm_start_batch_norm(
    net: TerrainCNN,
    images: np.ndarray,
    device: torch.device,
    rng: np.random.Generator,
    count: int = 256,
) -> None:
    """Set the batch-norm running statistics from a first batch of data.

    With weights from N(0, 0.01) the activations' variance is ~1e-4, while PyTorch starts
    the running variance at 1; at momentum 0.1 it takes a few hundred steps to forget
    that, and a model evaluated before then is wrong in eval mode only.
    """
    idx = rng.choice(len(images), size=min(count, len(images)), replace=False)
    norms = [m for m in net.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    momenta = [m.momentum for m in norms]
    for m in norms:
        m.momentum = 1.0
    net.train()
    net(images_to_tensor(images[np.sort(idx)]).to(device))
    for m, momentum in zip(norms, momenta):
        m.momentum = momentum


def keep_freed_memory() -> bool:
    """Let this process keep the memory it frees for its next allocations (glibc; elsewhere
    a no-op, False). For a training process only: every step allocates and frees conv1's
    output for the batch (64 x 16 x 100 x 100 float32, 41 MB), above the 32 MB that glibc
    ever serves from its heap. Without this, glibc gives it back to the system at every
    free and the kernel zeroes 41 MB of fresh pages for the next step: a third of the
    training time goes to the kernel."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_mmap_max = -1, -4  # glibc's malloc.h
    return bool(mallopt(m_mmap_max, 0)) and bool(mallopt(m_trim_threshold, 2**30))


def train(
    sessions: list[LabeledSession],
    settings: TrainSettings = TrainSettings(),
    show_progress: bool = True,
    on_epoch: Callable[[dict], None] | None = None,
) -> TrainResult:
    """Train a TerrainCNN on sessions (split by session); see the module docstring.
    `on_epoch`: called with each epoch's entry of the history."""
    from tqdm import tqdm

    started = time.perf_counter()
    world = _World.current()
    if settings.threads:
        torch.set_num_threads(settings.threads)
    torch.manual_seed(settings.seed)
    torch.use_deterministic_algorithms(True, warn_only=True)
    rng = np.random.default_rng(settings.seed)
    # Distributed, every process draws the same epochs (`rng`) and augments its own share
    # with its own generator.
    augment_rng = rng if world is None else np.random.default_rng([settings.seed, world.rank])
    device = choose_device(settings.device)

    train_s, val_s, test_s = split_by_session(
        sessions, settings.val_fraction, settings.test_fraction, settings.seed
    )
    x_train, y_train = _stack(train_s)
    x_val, y_val = _stack(val_s)
    if not len(y_train):
        raise InferenceError("the training sessions hold no labelled frames")
    absent = [m for m, c in zip(MODES, np.bincount(y_train, minlength=len(MODES))) if c == 0]
    if absent:
        log.warning("no training frames of %s", ", ".join(absent))

    net = TerrainCNN(hidden=settings.hidden).to(device, memory_format=torch.channels_last)
    optimiser = torch.optim.Adam(
        net.parameters(), lr=settings.lr, weight_decay=settings.weight_decay
    )
    scheduler = torch.optim.lr_scheduler.ReduceLROnPlateau(optimiser, factor=0.5, patience=0)
    _warm_start_batch_norm(net, x_train, device, rng)
    model = net
    batch_size = settings.batch_size
    if world is not None:
        from torch.nn.parallel import DistributedDataParallel

        model = DistributedDataParallel(net)  # the same start everywhere: rank 0's weights
        batch_size = max(1, settings.batch_size // world.size)
    per_epoch = settings.samples_per_epoch or len(y_train)
    bf16 = settings.bf16 and device.type == "cpu" and _native_bf16()
    best_loss, best_state, best_epoch, stale = math.inf, None, 0, 0
    history, steps, stopped_early, out_of_time = [], 0, False, False

    for epoch in range(1, settings.epochs + 1):
        net.train()
        order = _epoch_indices(y_train, per_epoch, settings.balance, rng, settings.balance_power)
        if world is not None:  # equal shares: every process takes as many steps
            order = order[: len(order) - len(order) % world.size][world.rank :: world.size]
        n_batches = math.ceil(len(order) / batch_size)
        loss_sum = correct = seen = 0
        with tqdm(
            total=n_batches,
            desc=f"epoch {epoch}/{settings.epochs}",
            unit="batch",
            disable=not show_progress,
            leave=True,
            dynamic_ncols=True,
        ) as bar:
            for x, y in _batches(
                x_train,
                y_train,
                order,
                batch_size,
                settings.augment_probability if settings.augment else 0.0,
                augment_rng,
                settings.mirror_probability if settings.augment else 0.0,
            ):
                x, y = x.to(device), y.to(device)
                with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
                    scores = model(x)
                loss = F.cross_entropy(scores.float(), y)
                optimiser.zero_grad(set_to_none=True)
                loss.backward()
                optimiser.step()
                steps += 1
                loss_sum += loss.item() * len(y)
                correct += int((scores.argmax(1) == y).sum())
                seen += len(y)
                bar.set_postfix(loss=f"{loss_sum / seen:.3f}", acc=f"{correct / seen:.3f}")
                bar.update(1)
                if settings.max_steps and steps >= settings.max_steps:
                    break
                if settings.max_seconds:
                    late = time.perf_counter() - started > settings.max_seconds
                    if late if world is None else world.any(late):  # all stop at one step
                        out_of_time = True
                        break
            if world is not None:
                loss_sum, correct, seen = world.sum([loss_sum, correct, seen])
            val_loss, val_acc, val_bal = _validate(
                net,
                x_val,
                y_val,
                device,
                settings.balance_power if settings.balance else 0.0,
                world=world,
            )
            bar.set_postfix(
                loss=f"{loss_sum / seen:.3f}",
                acc=f"{correct / seen:.3f}",
                val_loss=f"{val_loss:.3f}",
                val_acc=f"{val_acc:.3f}",
            )
        lr = optimiser.param_groups[0]["lr"]
        history.append(
            {
                "epoch": epoch,
                "train_loss": loss_sum / seen,
                "train_accuracy": correct / seen,
                "val_loss": val_loss,
                "val_accuracy": val_acc,
                "val_balanced_accuracy": val_bal,
                "lr": lr,
            }
        )
        if on_epoch is not None:
            on_epoch(dict(history[-1]))
        improved = not math.isnan(val_loss) and val_loss < best_loss - 1e-4
        if improved or best_state is None:
            best_loss = val_loss if not math.isnan(val_loss) else best_loss
            best_state, best_epoch, stale = copy.deepcopy(net.state_dict()), epoch, 0
        else:
            stale += 1
        if not math.isnan(val_loss):
            scheduler.step(val_loss)
        if (settings.max_steps and steps >= settings.max_steps) or out_of_time:
            break
        if stale >= settings.patience:
            stopped_early = True
            log.info("early stop after epoch %d (best %d)", epoch, best_epoch)
            break

    net.load_state_dict(best_state)
    net.eval()
    result = TrainResult(
        net=net.cpu(),
        history=history,
        best_epoch=best_epoch,
        split={
            "train": [s.name for s in train_s],
            "validation": [s.name for s in val_s],
            "test": [s.name for s in test_s],
        },
        data={
            "train": summarize(train_s),
            "validation": summarize(val_s),
            "test": summarize(test_s),
        },
        stopped_early=stopped_early,
    )
    if test_s and (world is None or world.rank == 0):
        result.test_metrics = evaluate_sessions(Classifier(result.net), test_s)
    result.seconds = time.perf_counter() - started
    return result


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
