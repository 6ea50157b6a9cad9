"""The terrain classifier: the paper's CNN, its weights file with metadata, and inference.

Network (Zhang et al. 2019, "Classifying the single environmental image"): a 100 x 100
binary image; three 3 x 3 convolutions with 16, 32 and 64 channels, each followed by batch
normalisation and ReLU; two 2 x 2 max-pools; flatten; fully connected layers to five
scores (LG, US, DS, UR, DR); conv and FC weights drawn from N(0, 0.01). The softmax of the
scores is the HMM's emission probability.

Choices the paper leaves open (documented here and in the metadata):
- Convolutions are padded ("same"), so only the pools shrink the image: 100 -> 50 -> 25.
- The pools follow the first two convolutions (conv-pool, conv-pool, conv), the cheapest
  order with two pools; the flattened features are 64 x 25 x 25.
- One hidden fully connected layer of `hidden` units (32 by default) with ReLU: "fully
  connected layers" is plural, and 32 keeps the file near 5 MB and inference fast.
- Biases start at zero; batch-norm scale 1, shift 0 (PyTorch's defaults).

Files: the weights are a PyTorch state dict (`<name>.pt`, read with
`torch.load(weights_only=True)`, which cannot run code) and the metadata sits next to it
(`<name>.json`: classes, input size, architecture, preprocessing parameters, data summary,
metrics and the weights' SHA-256). Anything missing, corrupt or mismatched is one
InferenceError line.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from devices.frames import MODES
from inference.errors import InferenceError

log = logging.getLogger(__name__)

FORMAT = "walkcap-terrain-cnn"
FORMAT_VERSION = 1
INPUT_SIZE = 100
CHANNELS = (16, 32, 64)
DEFAULT_HIDDEN = 32
INIT_STD = 0.01
BUNDLED_PATH = Path(__file__).resolve().parent / "models" / "terrain_cnn.pt"


def max_pool_2x2(x: torch.Tensor) -> torch.Tensor:
    """2 x 2 max-pool, stride 2 (even sizes). Same values as F.max_pool2d, built from four
    strided views: for inference on this CPU it is 3-30x faster than PyTorch's kernel
    (its backward is slow, so training uses F.max_pool2d)."""
    return torch.maximum(torch.maximum(x[..., 0::2, 0::2], x[..., 0::2, 1::2]),
                         torch.maximum(x[..., 1::2, 0::2], x[..., 1::2, 1::2]))


class TerrainCNN(nn.Module):
    """The paper's classifier; returns the five raw scores (logits) per image."""

    def __init__(self, hidden: int = DEFAULT_HIDDEN, input_size: int = INPUT_SIZE) -> None:
        super().__init__()
        if input_size % 4:
            raise InferenceError(f"input size must be a multiple of 4, got {input_size}")
        c1, c2, c3 = CHANNELS
        self.hidden = hidden
        self.input_size = input_size
        self.conv1 = nn.Conv2d(1, c1, 3, padding=1)
        self.bn1 = nn.BatchNorm2d(c1)
        self.conv2 = nn.Conv2d(c1, c2, 3, padding=1)
        self.bn2 = nn.BatchNorm2d(c2)
        self.conv3 = nn.Conv2d(c2, c3, 3, padding=1)
        self.bn3 = nn.BatchNorm2d(c3)
        self.fc1 = nn.Linear(c3 * (input_size // 4) ** 2, hidden)
        self.fc2 = nn.Linear(hidden, len(MODES))
        init_weights(self)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x: (N, 1, H, W) float, 0/1. Returns (N, 5) scores."""
        # Pool before ReLU: the same result (both are monotonic), a quarter of the work.
        # Train in channels-last memory format: 3x faster batch norm and pooling on CPU.
        x = F.relu(F.max_pool2d(self.bn1(self.conv1(x)), 2))
        x = F.relu(F.max_pool2d(self.bn2(self.conv2(x)), 2))
        x = F.relu(self.bn3(self.conv3(x)))
        x = F.relu(self.fc1(x.flatten(1)))
        return self.fc2(x)


def init_weights(net: nn.Module, std: float = INIT_STD) -> None:
    """The paper's initialisation: conv and FC weights from N(0, std), biases zero."""
    for m in net.modules():
        if isinstance(m, (nn.Conv2d, nn.Linear)):
            nn.init.normal_(m.weight, 0.0, std)
            nn.init.zeros_(m.bias)


def _fold(conv: nn.Conv2d, bn: nn.BatchNorm2d) -> tuple[torch.Tensor, torch.Tensor]:
    """Batch norm (eval) folded into the convolution before it."""
    scale = bn.weight / torch.sqrt(bn.running_var + bn.eps)
    weight = conv.weight * scale[:, None, None, None]
    bias = (conv.bias - bn.running_mean) * scale + bn.bias
    return weight.detach().clone(), bias.detach().clone()


class _FoldedCNN:
    """The trained network for CPU inference, the same scores as TerrainCNN.eval() to
    float precision, two to four times as fast:
    - batch norm folded into the convolutions; pool before ReLU (they commute);
    - the first block (conv, BN, pool, ReLU) as a table: on a binary image each pooled
      output depends only on a 4 x 4 input patch, so its 16 values are looked up by the
      patch's 16-bit code (65536 x 16 floats, built once from the folded conv1);
    - channels-last memory format for the other convolutions.
    """

    def __init__(self, net: TerrainCNN) -> None:
        cl = torch.channels_last
        w1, b1 = _fold(net.conv1, net.bn1)
        self.w1, self.b1 = w1, b1
        with torch.inference_mode():
            codes = torch.arange(1 << 16)
            bits = (codes[:, None] >> torch.arange(16)) & 1
            # Bit 4k + 2r + c: cell (r, c) of 2 x 2 block k (top-left, top-right,
            # bottom-left, bottom-right) of the 4 x 4 patch.
            patches = bits.view(-1, 2, 2, 2, 2).permute(0, 1, 3, 2, 4).reshape(-1, 1, 4, 4)
            self.table = F.conv2d(patches.float(), w1, b1).amax(dim=(2, 3)).relu_()
        self.block_weights = torch.tensor([[1, 2], [4, 8]], dtype=torch.int32)
        w2, self.b2 = _fold(net.conv2, net.bn2)
        w3, self.b3 = _fold(net.conv3, net.bn3)
        self.w2 = w2.contiguous(memory_format=cl)
        self.w3 = w3.contiguous(memory_format=cl)
        self.fc1_w, self.fc1_b = net.fc1.weight.detach().clone(), net.fc1.bias.detach().clone()
        self.fc2_w, self.fc2_b = net.fc2.weight.detach().clone(), net.fc2.bias.detach().clone()

    def first_block(self, x: torch.Tensor) -> torch.Tensor:
        """relu(pool(bn(conv1(x)))) of a binary (N, 1, H, W) batch, by table lookup."""
        n, _, h, w = x.shape
        padded = F.pad(x[:, 0].to(torch.int32), (1, 1, 1, 1))  # conv1's padding
        # 4-bit code of every 2 x 2 block, then 16 bits from four neighbouring blocks.
        blocks = padded.view(n, h // 2 + 1, 2, w // 2 + 1, 2).permute(0, 1, 3, 2, 4)
        block = (blocks * self.block_weights).sum(dim=(3, 4))
        code = (block[:, :-1, :-1] + (block[:, :-1, 1:] << 4)
                + (block[:, 1:, :-1] << 8) + (block[:, 1:, 1:] << 12))
        out = self.table[code.reshape(-1)].view(n, h // 2, w // 2, -1)
        return out.permute(0, 3, 1, 2)  # (N, C, H/2, W/2), channels-last in memory

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        y = self.first_block(x)
        y = max_pool_2x2(F.conv2d(y, self.w2, self.b2, padding=1)).relu_()
        y = F.conv2d(y, self.w3, self.b3, padding=1).relu_()
        y = F.linear(y.flatten(1), self.fc1_w, self.fc1_b).relu_()
        return F.linear(y, self.fc2_w, self.fc2_b)


def choose_device(device: str = "auto") -> torch.device:
    """"auto": the GPU when there is one, else the CPU."""
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device not in ("cpu", "cuda"):
        raise InferenceError(f"unknown device {device!r} (use auto, cpu or cuda)")
    if device == "cuda" and not torch.cuda.is_available():
        raise InferenceError("device 'cuda' requested but no GPU is available")
    return torch.device(device)


def images_to_tensor(images: np.ndarray) -> torch.Tensor:
    """(N, H, W) or (H, W) binary images (any nonzero cell is occupied) -> (N, 1, H, W)
    float32 of 0 and 1."""
    a = np.asarray(images)
    if a.ndim == 2:
        a = a[None]
    return torch.from_numpy((a != 0).astype(np.float32)).unsqueeze(1)


@dataclass
class Classifier:
    """A loaded terrain classifier. `predict` for one live frame, `predict_batch` for
    replay; both return softmax probabilities in MODES order."""

    net: TerrainCNN
    metadata: dict = field(default_factory=dict)
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))
    path: str = ""

    def __post_init__(self) -> None:
        self.net.eval().to(self.device)
        self._forward = _FoldedCNN(self.net) if self.device.type == "cpu" else self.net
        self.input_size = self.net.input_size

    @property
    def classes(self) -> tuple[str, ...]:
        return MODES

    def _check(self, images: np.ndarray) -> np.ndarray:
        a = np.asarray(images)
        if a.shape[-2:] != (self.input_size, self.input_size):
            raise InferenceError(f"classifier input must be {self.input_size} x "
                                 f"{self.input_size}, got {a.shape[-2:]}")
        return a

    def predict(self, image: np.ndarray) -> np.ndarray:
        """One (H, W) binary image -> (5,) probabilities (float64, sum 1)."""
        a = self._check(image)
        if a.ndim != 2:
            raise InferenceError(f"predict takes one image (H, W), got shape {a.shape}")
        return self.predict_batch(a[None])[0]

    def predict_batch(self, images: np.ndarray, batch_size: int = 16) -> np.ndarray:
        """(N, H, W) binary images -> (N, 5) probabilities. Small batches are fastest on
        CPU (the activations of 16 images stay in cache)."""
        a = self._check(images)
        if a.ndim != 3:
            raise InferenceError(f"predict_batch takes (N, H, W) images, got shape {a.shape}")
        out = np.empty((len(a), len(MODES)), dtype=np.float64)
        with torch.inference_mode():
            for i in range(0, len(a), batch_size):
                x = images_to_tensor(a[i:i + batch_size]).to(self.device)
                out[i:i + batch_size] = torch.softmax(self._forward(x).double(), 1).cpu().numpy()
        return out


# ---- files -------------------------------------------------------------------------------

def metadata_path(weights: str | os.PathLike) -> Path:
    return Path(weights).with_suffix(".json")


def file_sha256(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def architecture(net: TerrainCNN) -> dict:
    return {"name": "TerrainCNN", "channels": list(CHANNELS), "kernel": 3, "padding": "same",
            "pools": "after conv1 and conv2", "hidden": net.hidden, "init_std": INIT_STD}


def save_model(net: TerrainCNN, path: str | os.PathLike, metadata: dict | None = None) -> Path:
    """Write `<path>` (state dict) and `<path>.json` (metadata with the weights' hash).
    Both are written atomically; returns the weights path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().cpu().contiguous() for k, v in net.state_dict().items()}
    tmp = path.with_name(path.name + ".tmp")
    torch.save(state, tmp)
    os.replace(tmp, path)
    meta = dict(metadata or {})
    meta.update({
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "classes": list(MODES),
        "input_size": [net.input_size, net.input_size],
        "architecture": architecture(net),
        "weights_file": path.name,
        "weights_sha256": file_sha256(path),
        "weights_bytes": path.stat().st_size,
    })
    meta.setdefault("created", time.strftime("%Y-%m-%dT%H:%M:%S%z"))
    mpath = metadata_path(path)
    tmp = mpath.with_name(mpath.name + ".tmp")
    tmp.write_text(json.dumps(meta, indent=2, sort_keys=False) + "\n")
    os.replace(tmp, mpath)
    return path


def read_metadata(path: str | os.PathLike) -> dict:
    """The metadata of the weights file at `path`, validated; InferenceError otherwise."""
    path = Path(path)
    mpath = metadata_path(path)
    if not mpath.is_file():
        raise InferenceError(f"model metadata not found: {mpath} (it belongs next to {path.name})")
    try:
        meta = json.loads(mpath.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InferenceError(f"model metadata {mpath} is corrupt: {e}") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise InferenceError(f"{mpath} is not walkcap terrain-classifier metadata")
    if meta.get("format_version") != FORMAT_VERSION:
        raise InferenceError(f"{mpath}: format version {meta.get('format_version')!r}, "
                             f"this walkcap reads {FORMAT_VERSION}")
    if meta.get("classes") != list(MODES):
        raise InferenceError(f"model {path} classifies {meta.get('classes')!r}, "
                             f"walkcap needs {list(MODES)}")
    if meta.get("input_size") != [INPUT_SIZE, INPUT_SIZE]:
        raise InferenceError(f"model {path} takes {meta.get('input_size')!r} images, "
                             f"walkcap's preprocessing makes {INPUT_SIZE} x {INPUT_SIZE}")
    hidden = meta.get("architecture", {}).get("hidden")
    if not isinstance(hidden, int) or hidden < 1:
        raise InferenceError(f"{mpath}: architecture.hidden must be a positive integer")
    return meta


def load_classifier(path: str | os.PathLike | None = None, device: str = "auto",
                    threads: int | None = None) -> Classifier:
    """Load a classifier; None or "" loads the bundled model.

    A missing file, a corrupt file (hash, unreadable) or a file that does not fit the
    network or walkcap's classes/input size raises InferenceError with one line.
    `threads` sets torch's intra-op threads for the process (1 gives the steadiest
    single-frame latency when other threads share the CPU).
    """
    weights = Path(path) if path else BUNDLED_PATH
    if weights.suffix == ".json":
        weights = weights.with_suffix(".pt")
    if not weights.is_file():
        hint = " (the bundled model is missing: reinstall walkcap)" if not path else ""
        raise InferenceError(f"model file not found: {weights}{hint}")
    meta = read_metadata(weights)
    if file_sha256(weights) != meta.get("weights_sha256"):
        raise InferenceError(f"model file {weights} is corrupt: its SHA-256 does not match "
                             f"{metadata_path(weights).name}")
    try:
        state = torch.load(weights, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises many types for a bad file
        raise InferenceError(f"model file {weights} is corrupt or not a state dict: "
                             f"{type(e).__name__}") from None
    net = TerrainCNN(hidden=meta["architecture"]["hidden"])
    if not isinstance(state, dict):
        raise InferenceError(f"model file {weights} does not hold a state dict")
    expected = net.state_dict()
    problems = [k for k in expected if k not in state]
    problems += [k for k in state if k not in expected]
    problems += [f"{k} {tuple(state[k].shape)} != {tuple(v.shape)}" for k, v in expected.items()
                 if k in state and hasattr(state[k], "shape") and state[k].shape != v.shape]
    if problems:
        raise InferenceError(f"model file {weights} does not match the network: "
                             f"{'; '.join(problems[:3])}")
    net.load_state_dict(state)
    if threads:
        torch.set_num_threads(threads)
    clf = Classifier(net, meta, choose_device(device), str(weights))
    log.info("loaded terrain classifier %s (%s)", weights, meta.get("weights_sha256", "")[:12])
    return clf


# ---- benchmark ---------------------------------------------------------------------------

def bench_cnn(frames: int = 500, path: str | None = None, threads: int = 2) -> dict:
    """Single-frame latency (median ms) and batched throughput (frames/s) on the CPU.

    Random binary images of realistic sparsity; the bundled model if it exists, else an
    untrained network (same cost). `threads` applies to the single-frame figure; the
    batched figure uses every core.
    """
    rng = np.random.default_rng(0)
    images = (rng.random((frames, INPUT_SIZE, INPUT_SIZE)) < 0.03).astype(np.uint8)
    try:
        clf = load_classifier(path, device="cpu")
    except InferenceError:
        clf = Classifier(TerrainCNN(), {}, torch.device("cpu"))
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(threads)
        for img in images[:20]:
            clf.predict(img)
        times = []
        for img in images:
            t = time.perf_counter()
            clf.predict(img)
            times.append(time.perf_counter() - t)
        torch.set_num_threads(os.cpu_count() or 1)
        clf.predict_batch(images[:32])
        t = time.perf_counter()
        clf.predict_batch(images)
        rate = frames / (time.perf_counter() - t)
    finally:
        torch.set_num_threads(before)
    return {"cnn_frame_ms": float(np.median(times) * 1e3), "cnn_batch_rate": float(rate)}
