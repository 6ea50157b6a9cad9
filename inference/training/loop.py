"""The training loop: one run's set-up, its epochs, early stopping on the validation loss
and the best weights kept (the package docstring says what and why)."""

from __future__ import annotations

import copy
import ctypes
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.nn.functional as F

from devices.frames import MODES
from inference.dataset import LabeledSession, summarize
from inference.errors import InferenceError
from inference.evaluation.metrics import confusion_matrix
from inference.model import Classifier, TerrainCNN, choose_device, images_to_tensor
from inference.training.data import batches, epoch_indices, split_by_session, stack_labelled
from inference.training.metrics import confusion_metrics, evaluate_sessions
from inference.training.settings import TrainSettings

log = logging.getLogger(__name__)


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


def train(
    sessions: list[LabeledSession],
    settings: TrainSettings | None = None,
    show_progress: bool = True,
    on_epoch: Callable[[dict], None] | None = None,
) -> TrainResult:
    """Train a TerrainCNN on sessions (split by session); see the package docstring.
    `on_epoch`: called with each epoch's entry of the history."""
    settings = settings or TrainSettings()
    started = time.perf_counter()
    run = _start(settings, started)
    frames = _Frames.split(sessions, settings)
    fit = _Fit.new(settings, run, frames.x_train)
    best = _Best()
    history: list[dict] = []
    steps, stopped_early = 0, False
    for epoch in range(1, settings.epochs + 1):
        entry, steps, out_of_time = _train_epoch(epoch, run, frames, fit, steps, show_progress)
        history.append(entry)
        if on_epoch is not None:
            on_epoch(dict(entry))
        best.update(fit.net, epoch, entry["val_loss"])
        if not math.isnan(entry["val_loss"]):
            fit.scheduler.step(entry["val_loss"])
        if (settings.max_steps and steps >= settings.max_steps) or out_of_time:
            break
        if best.stale >= settings.patience:
            stopped_early = True
            log.info("early stop after epoch %d (best %d)", epoch, best.epoch)
            break
    return _result(run, frames, fit.net, best, history, stopped_early)


@dataclass
class _Run:
    """Where and how one training run works: the same draws in every process (`rng`: the
    epochs' frames, the batch-norm warm start), each its own augmentation (`augment_rng`)."""

    settings: TrainSettings
    started: float  # time.perf_counter() at the start: max_seconds counts from it
    world: _World | None
    device: torch.device
    rng: np.random.Generator
    augment_rng: np.random.Generator
    bf16: bool


def _start(settings: TrainSettings, started: float) -> _Run:
    """Threads, seeds and deterministic algorithms, the device and the generators."""
    world = _World.current()
    if settings.threads:
        torch.set_num_threads(settings.threads)
    torch.manual_seed(settings.seed)
    torch.use_deterministic_algorithms(True, warn_only=True)
    rng = np.random.default_rng(settings.seed)
    augment_rng = rng if world is None else np.random.default_rng([settings.seed, world.rank])
    device = choose_device(settings.device)
    bf16 = settings.bf16 and device.type == "cpu" and _native_bf16()
    return _Run(settings, started, world, device, rng, augment_rng, bf16)


@dataclass
class _Frames:
    """The sessions split by session, and the training and validation frames stacked."""

    train: list[LabeledSession]
    validation: list[LabeledSession]
    test: list[LabeledSession]
    x_train: np.ndarray
    y_train: np.ndarray
    x_val: np.ndarray
    y_val: np.ndarray

    @classmethod
    def split(cls, sessions: list[LabeledSession], settings: TrainSettings) -> _Frames:
        train_s, val_s, test_s = split_by_session(
            sessions, settings.val_fraction, settings.test_fraction, settings.seed
        )
        x_train, y_train = stack_labelled(train_s)
        x_val, y_val = stack_labelled(val_s)
        if not len(y_train):
            raise InferenceError("the training sessions hold no labelled frames")
        counts = np.bincount(y_train, minlength=len(MODES))
        absent = [m for m, c in zip(MODES, counts) if c == 0]
        if absent:
            log.warning("no training frames of %s", ", ".join(absent))
        return cls(train_s, val_s, test_s, x_train, y_train, x_val, y_val)


@dataclass
class _Fit:
    """The network, what steps it (optimiser, learning-rate schedule) and what runs it
    (`model`: the network, or its DistributedDataParallel; `batch_size`: this process's)."""

    net: TerrainCNN
    model: torch.nn.Module
    optimiser: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.ReduceLROnPlateau
    batch_size: int

    @classmethod
    def new(cls, settings: TrainSettings, run: _Run, x_train: np.ndarray) -> _Fit:
        net = TerrainCNN(hidden=settings.hidden).to(run.device, memory_format=torch.channels_last)
        optimiser = torch.optim.Adam(
            net.parameters(), lr=settings.lr, weight_decay=settings.weight_decay
        )
        scheduler = torch.optim.lr_scheduler.ReduceLROnPlateau(optimiser, factor=0.5, patience=0)
        _warm_start_batch_norm(net, x_train, run.device, run.rng)
        model: torch.nn.Module = net
        batch_size = settings.batch_size
        if run.world is not None:
            from torch.nn.parallel import DistributedDataParallel

            model = DistributedDataParallel(net)  # the same start everywhere: rank 0's weights
            batch_size = max(1, settings.batch_size // run.world.size)
        return cls(net, model, optimiser, scheduler, batch_size)


@dataclass
class _Best:
    """Early stopping: the best validation loss so far, its epoch and weights, and the
    epochs since."""

    loss: float = math.inf
    state: dict | None = None
    epoch: int = 0
    stale: int = 0

    def update(self, net: TerrainCNN, epoch: int, val_loss: float) -> None:
        improved = not math.isnan(val_loss) and val_loss < self.loss - 1e-4
        if improved or self.state is None:
            self.loss = val_loss if not math.isnan(val_loss) else self.loss
            self.state, self.epoch, self.stale = copy.deepcopy(net.state_dict()), epoch, 0
        else:
            self.stale += 1


def _train_epoch(
    epoch: int, run: _Run, frames: _Frames, fit: _Fit, steps: int, show_progress: bool
) -> tuple[dict, int, bool]:
    """One epoch's steps, then validation: (its history entry, the steps taken in all,
    whether the time budget ran out)."""
    from tqdm import tqdm

    settings, world = run.settings, run.world
    per_epoch = settings.samples_per_epoch or len(frames.y_train)
    fit.net.train()
    order = epoch_indices(
        frames.y_train, per_epoch, settings.balance, run.rng, settings.balance_power
    )
    if world is not None:  # equal shares: every process takes as many steps
        order = order[: len(order) - len(order) % world.size][world.rank :: world.size]
    n_batches = math.ceil(len(order) / fit.batch_size)
    loss_sum = correct = seen = 0
    out_of_time = False
    with tqdm(
        total=n_batches,
        desc=f"epoch {epoch}/{settings.epochs}",
        unit="batch",
        disable=not show_progress,
        leave=True,
        dynamic_ncols=True,
    ) as bar:
        for x, y in batches(
            frames.x_train,
            frames.y_train,
            order,
            fit.batch_size,
            settings.augment_probability if settings.augment else 0.0,
            run.augment_rng,
            settings.mirror_probability if settings.augment else 0.0,
        ):
            x, y = x.to(run.device), y.to(run.device)
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=run.bf16):
                scores = fit.model(x)
            loss = F.cross_entropy(scores.float(), y)
            fit.optimiser.zero_grad(set_to_none=True)
            loss.backward()
            fit.optimiser.step()
            steps += 1
            loss_sum += loss.item() * len(y)
            correct += int((scores.argmax(1) == y).sum())
            seen += len(y)
            bar.set_postfix(loss=f"{loss_sum / seen:.3f}", acc=f"{correct / seen:.3f}")
            bar.update(1)
            if settings.max_steps and steps >= settings.max_steps:
                break
            if settings.max_seconds:
                late = time.perf_counter() - run.started > settings.max_seconds
                if late if world is None else world.any(late):  # all stop at one step
                    out_of_time = True
                    break
        if world is not None:
            loss_sum, correct, seen = world.sum([loss_sum, correct, seen])
        val_loss, val_acc, val_bal = _validate(
            fit.net,
            frames.x_val,
            frames.y_val,
            run.device,
            settings.balance_power if settings.balance else 0.0,
            world=world,
        )
        bar.set_postfix(
            loss=f"{loss_sum / seen:.3f}",
            acc=f"{correct / seen:.3f}",
            val_loss=f"{val_loss:.3f}",
            val_acc=f"{val_acc:.3f}",
        )
    entry = {
        "epoch": epoch,
        "train_loss": loss_sum / seen,
        "train_accuracy": correct / seen,
        "val_loss": val_loss,
        "val_accuracy": val_acc,
        "val_balanced_accuracy": val_bal,
        "lr": fit.optimiser.param_groups[0]["lr"],
    }
    return entry, steps, out_of_time


def _result(
    run: _Run,
    frames: _Frames,
    net: TerrainCNN,
    best: _Best,
    history: list[dict],
    stopped_early: bool,
) -> TrainResult:
    """The best epoch's network, the history and the split; measured on the test sessions
    (by the first process when distributed)."""
    net.load_state_dict(best.state)
    net.eval()
    parts = {"train": frames.train, "validation": frames.validation, "test": frames.test}
    result = TrainResult(
        net=net.cpu(),
        history=history,
        best_epoch=best.epoch,
        split={name: [s.name for s in part] for name, part in parts.items()},
        data={name: summarize(part) for name, part in parts.items()},
        stopped_early=stopped_early,
    )
    if frames.test and (run.world is None or run.world.rank == 0):
        result.test_metrics = evaluate_sessions(Classifier(result.net), frames.test)
    result.seconds = time.perf_counter() - run.started
    return result


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
