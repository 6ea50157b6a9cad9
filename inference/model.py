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
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from devices.files import check_replaceable
from devices.frames import MODES
from inference.errors import InferenceError

log = logging.getLogger(__name__)

FORMAT = "walkcap-terrain-cnn"
FORMAT_VERSION = 1
INPUT_SIZE = 100
CHANNELS = (16, 32, 64)
DEFAULT_HIDDEN = 32
HIDDEN_MAX = 1024  # fc1 holds 40,000 weights a unit: 160 MB at this size
INIT_STD = 0.01
BUNDLED_PATH = Path(__file__).resolve().parent / "models" / "terrain_cnn.pt"


def max_pool_2x2(x: torch.Tensor) -> torch.Tensor:
    """2 x 2 max-pool, stride 2 (even sizes). Same values as F.max_pool2d, built from four
    strided views: for CPU inference it is 3-30x faster than PyTorch's kernel
    (its backward is slow, so training uses F.max_pool2d)."""
    return torch.maximum(
        torch.maximum(x[..., 0::2, 0::2], x[..., 0::2, 1::2]),
        torch.maximum(x[..., 1::2, 0::2], x[..., 1::2, 1::2]),
    )


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


BUSY = 0.12  # above this share of occupied 4 x 4 patches dense convolutions are cheaper


def _patch_codes(images: np.ndarray) -> np.ndarray:
    """The 16-bit code of every 4 x 4 patch, stride 2, of (N, H, W) binary images zero-padded
    by one cell (conv1's padding): bit 4k + 2r + c is cell (r, c) of 2 x 2 block k (top-left,
    top-right, bottom-left, bottom-right). (N, H/2, W/2) int32 (int64 takes twice as long)."""
    n, h, w = images.shape
    padded = np.zeros((n, h + 2, w + 2), np.int32)
    padded[:, 1:-1, 1:-1] = images != 0
    cells = padded.reshape(n, h // 2 + 1, 2, w // 2 + 1, 2)
    block = (
        cells[:, :, 0, :, 0]
        | cells[:, :, 0, :, 1] << 1
        | cells[:, :, 1, :, 0] << 2
        | cells[:, :, 1, :, 1] << 3
    )
    return (
        block[:, :-1, :-1]
        | block[:, :-1, 1:] << 4
        | block[:, 1:, :-1] << 8
        | block[:, 1:, 1:] << 12
    )


def occupied_patches(images: np.ndarray) -> np.ndarray:
    """Which 4 x 4 patches of each image hold terrain: what the sparse path's cost follows."""
    return _patch_codes(images) != 0


def _nhwc(x: torch.Tensor) -> torch.Tensor:
    """(N, C, H, W) -> (N, H, W, C), contiguous."""
    return x.permute(0, 2, 3, 1).contiguous()


class _FoldedCNN:
    """The trained network for CPU inference, the same scores as TerrainCNN.eval() to
    float precision, several times as fast:
    - batch norm folded into the convolutions; pool before ReLU (they commute);
    - the first block (conv, BN, pool, ReLU) as a table: on a binary image each pooled
      output depends only on a 4 x 4 input patch, so its 16 values are looked up by the
      patch's 16-bit code (65536 x 16 floats, built once from the folded conv1);
    - sparse convolutions: a terrain image is mostly empty, and every empty patch gives the
      same first-block output. The activations of an all-empty image (the background) are
      computed once; a frame adds only the change its occupied patches make, at those
      cells and their 3 x 3 neighbours;
    - the band: the terrain ahead fills a band of rows (a fifth of the image for a walk),
      and outside it every layer keeps its background value. So the pool, conv3 and fc1
      work on the band's rows only: fc1 is its background output plus the band's change
      times the band's rows of weights (a fifth of its 5 MB).
    Busier images (over BUSY) take the dense convolutions in channels-last memory format.
    The sparse path does its index arithmetic and slicing in numpy (about a microsecond an
    operation, torch's take four, and one frame has dozens) and its products in torch
    (which keeps to the thread count the session sets).
    """

    def __init__(self, net: TerrainCNN) -> None:
        cl = torch.channels_last
        w1, b1 = _fold(net.conv1, net.bn1)
        with torch.inference_mode():
            codes = torch.arange(1 << 16)
            bits = (codes[:, None] >> torch.arange(16)) & 1
            patches = bits.view(-1, 2, 2, 2, 2).permute(0, 1, 3, 2, 4).reshape(-1, 1, 4, 4)
            self.table = F.conv2d(patches.float(), w1, b1).amax(dim=(2, 3)).relu_()
            self.change = (self.table - self.table[0]).numpy()  # what an occupied patch adds
            w2, self.b2 = _fold(net.conv2, net.bn2)
            w3, self.b3 = _fold(net.conv3, net.bn3)
            self.w2 = w2.contiguous(memory_format=cl)
            self.w3 = w3.contiguous(memory_format=cl)
            # Per-tap weights (C_in, 9 * C_out), tap kr * 3 + kc, for the sparse path.
            self.taps2 = w2.permute(1, 2, 3, 0).reshape(w2.shape[1], -1).contiguous()
            self.taps3 = w3.permute(1, 2, 3, 0).reshape(w3.shape[1], -1).contiguous()
            # fc1 reads the last activations in (H, W, C) order, as channels-last stores them,
            # its weights as (H * W * C, hidden): a band of rows is one slice.
            s4, c3 = net.input_size // 4, w3.shape[0]
            self.fc1_rows = (
                net.fc1.weight.detach()
                .view(-1, c3, s4, s4)
                .permute(2, 3, 1, 0)
                .reshape(-1, net.fc1.out_features)
                .contiguous()
            )
            self.fc1_b = net.fc1.bias.detach().clone()
            self.fc2_w, self.fc2_b = net.fc2.weight.detach().clone(), net.fc2.bias.detach().clone()
            # The background, padded by one cell where a convolution follows.
            s2 = net.input_size // 2
            empty = self.table[0].view(1, -1, 1, 1).expand(1, -1, s2, s2)
            conv2 = F.conv2d(empty, w2, self.b2, padding=1)
            pooled = max_pool_2x2(conv2).relu_()
            conv3 = F.conv2d(pooled, w3, self.b3, padding=1)
            self.conv2_bg = _nhwc(F.pad(conv2, (1, 1, 1, 1)))[0].numpy()
            self.conv3_bg = _nhwc(F.pad(conv3, (1, 1, 1, 1)))[0].numpy()
            self.pooled_bg = _nhwc(pooled)[0].numpy()
            self.out_bg = self.conv3_bg[1:-1, 1:-1].clip(min=0)
            self.fc1_bg = torch.addmm(
                self.fc1_b, torch.from_numpy(self.out_bg).reshape(1, -1), self.fc1_rows
            )
        self.reach2, self.reach3 = _reach(s2 + 2), _reach(s4 + 2)

    def __call__(self, images: np.ndarray) -> torch.Tensor:
        """(N, H, W) binary images -> (N, 5) scores."""
        code = _patch_codes(images)
        occupied = np.flatnonzero(code)
        if len(occupied) > BUSY * code.size:
            y = self._dense(torch.from_numpy(code))
            hidden = torch.addmm(self.fc1_b, y.reshape(len(y), -1), self.fc1_rows)
        else:
            hidden = self._sparse(code, occupied)
        return F.linear(hidden.relu_(), self.fc2_w, self.fc2_b)

    def _dense(self, code: torch.Tensor) -> torch.Tensor:
        """The convolutions on whole images; (N, H/4, W/4, C) activations."""
        n, h, w = code.shape
        y = self.table[code.view(-1)].view(n, h, w, -1).permute(0, 3, 1, 2)
        y = max_pool_2x2(F.conv2d(y, self.w2, self.b2, padding=1)).relu_()
        return F.conv2d(y, self.w3, self.b3, padding=1).relu_().permute(0, 2, 3, 1)

    def _sparse(self, code: np.ndarray, occupied: np.ndarray) -> torch.Tensor:
        """fc1's output (N, hidden), before its ReLU, as background plus the change the
        occupied patches (flat indices into code, (N, S, S)) make within their band of rows
        (the union over the images)."""
        n, s2 = len(code), code.shape[1]
        s4 = s2 // 2
        if len(occupied) == 0:
            return self.fc1_bg.repeat(n, 1)
        image, cell = np.divmod(occupied, s2 * s2)
        row, col = np.divmod(cell, s2)
        r0, r1 = int(row.min()), int(row.max())
        # conv2 changes rows r0-1..r1+1; the pool takes whole pairs of them: pooled rows
        # pa..pb. The padded buffer's rows b0..b1-1 take every tap that lands.
        pa, pb = max(r0 - 1, 0) // 2, min(r1 + 1, s2 - 1) // 2
        b0, b1 = min(r0, 2 * pa + 1), max(r1 + 3, 2 * pb + 3)
        conv2 = _add_taps(
            self.conv2_bg[b0:b1],
            n,
            image,
            row - b0,
            col,
            self.change[code.reshape(-1)[occupied]],
            self.taps2,
            self.reach2,
        )
        y = conv2[:, 2 * pa + 1 - b0 : 2 * pb + 3 - b0, 1:-1]
        pooled = np.maximum(
            np.maximum(y[:, 0::2, 0::2], y[:, 0::2, 1::2]),
            np.maximum(y[:, 1::2, 0::2], y[:, 1::2, 1::2]),
        )
        change = (pooled.clip(min=0) - self.pooled_bg[pa : pb + 1]).reshape(-1, pooled.shape[-1])
        changed = np.flatnonzero(change.any(1))
        image, cell = np.divmod(changed, (pb + 1 - pa) * s4)
        row, col = np.divmod(cell, s4)
        conv3 = _add_taps(
            self.conv3_bg[pa : pb + 3], n, image, row, col, change[changed], self.taps3, self.reach3
        )
        q0, q1 = max(pa - 1, 0), min(pb + 2, s4)  # the rows conv3 changed
        out = conv3[:, q0 + 1 - pa : q1 + 1 - pa, 1:-1].clip(min=0) - self.out_bg[q0:q1]
        band = self.fc1_rows[q0 * s4 * out.shape[-1] : q1 * s4 * out.shape[-1]]
        return torch.addmm(self.fc1_bg, torch.from_numpy(out.reshape(n, -1)), band)


def _reach(p: int) -> np.ndarray:
    """Where each tap (kr, kc) of an input at (row, col) lands, as a flat offset in a map
    padded to width p: the output at (row + 1 - kr, col + 1 - kc), (row + 2 - kr, col + 2 - kc)
    padded."""
    return np.array([(2 - kr) * p + 2 - kc for kr in range(3) for kc in range(3)])


def _add_taps(
    background: np.ndarray,
    n: int,
    image: np.ndarray,
    row: np.ndarray,
    col: np.ndarray,
    change: np.ndarray,
    taps: torch.Tensor,
    reach: np.ndarray,
) -> np.ndarray:
    """A 3 x 3 convolution of (background input + change), channels last, for one band of
    rows of several images. A convolution is linear, so it is conv(background) (given: the
    band's rows of the padded (R, S+2, C_out) output) plus each changed cell's value times
    each tap's weights, added where that tap lands (`reach`, from _reach). The changed
    cells of the n images: image, row (within the band) and col, and their (K, C_in)
    values. (n, R, S+2, C_out), padded."""
    r, p, c_out = background.shape
    out = np.tile(background, (n, 1, 1, 1))
    target = (((image * r + row) * p + col)[:, None] + reach).reshape(-1)
    torch.from_numpy(out).view(-1, c_out).index_add_(
        0, torch.from_numpy(target), (torch.from_numpy(change) @ taps).view(-1, c_out)
    )
    return out


def choose_device(device: str = "auto") -> torch.device:
    """ "auto": the GPU when there is one, else the CPU."""
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
        self._folded = _FoldedCNN(self.net) if self.device.type == "cpu" else None
        self.input_size = self.net.input_size

    def _scores(self, images: np.ndarray) -> torch.Tensor:
        if self._folded is not None:
            return self._folded(images)
        return self.net(images_to_tensor(images).to(self.device))

    @property
    def classes(self) -> tuple[str, ...]:
        return MODES

    def _check(self, images: np.ndarray) -> np.ndarray:
        a = np.asarray(images)
        if a.shape[-2:] != (self.input_size, self.input_size):
            raise InferenceError(
                f"classifier input must be {self.input_size} x "
                f"{self.input_size}, got {a.shape[-2:]}"
            )
        return a

    def predict(self, image: np.ndarray) -> np.ndarray:
        """One (H, W) binary image -> (5,) probabilities (float64, sum 1)."""
        a = self._check(image)
        if a.ndim != 2:
            raise InferenceError(f"predict takes one image (H, W), got shape {a.shape}")
        with torch.inference_mode():
            return _softmax(self._scores(a[None]).cpu().numpy())[0]

    def predict_batch(self, images: np.ndarray, batch_size: int = 16) -> np.ndarray:
        """(N, H, W) binary images -> (N, 5) probabilities. Small batches are fastest on
        CPU (the activations of 16 images stay in cache)."""
        a = self._check(images)
        if a.ndim != 3:
            raise InferenceError(f"predict_batch takes (N, H, W) images, got shape {a.shape}")
        out = np.empty((len(a), len(MODES)), dtype=np.float64)
        with torch.inference_mode():
            for i in range(0, len(a), batch_size):
                out[i : i + batch_size] = _softmax(
                    self._scores(a[i : i + batch_size]).cpu().numpy()
                )
        return out


def _softmax(scores: np.ndarray) -> np.ndarray:
    """(N, 5) scores -> probabilities, in float64 (the HMM multiplies many of them)."""
    s = scores.astype(np.float64)
    e = np.exp(s - s.max(axis=1, keepdims=True))
    return e / e.sum(axis=1, keepdims=True)


def metadata_path(weights: str | os.PathLike) -> Path:
    return Path(weights).with_suffix(".json")


def file_sha256(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def architecture(net: TerrainCNN) -> dict:
    return {
        "name": "TerrainCNN",
        "channels": list(CHANNELS),
        "kernel": 3,
        "padding": "same",
        "pools": "after conv1 and conv2",
        "hidden": net.hidden,
        "init_std": INIT_STD,
    }


def save_model(net: TerrainCNN, path: str | os.PathLike, metadata: dict | None = None) -> Path:
    """Write `<path>` (state dict) and `<path>.json` (metadata with the weights' hash).
    Both are written atomically; returns the weights path."""
    path = check_replaceable(path)
    check_replaceable(metadata_path(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().cpu().contiguous() for k, v in net.state_dict().items()}
    tmp = path.with_name(path.name + ".tmp")
    torch.save(state, tmp)
    os.replace(tmp, path)
    meta = dict(metadata or {})
    meta.update(
        {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "classes": list(MODES),
            "input_size": [net.input_size, net.input_size],
            "architecture": architecture(net),
            "weights_file": path.name,
            "weights_sha256": file_sha256(path),
            "weights_bytes": path.stat().st_size,
        }
    )
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
        raise InferenceError(
            f"{mpath}: format version {meta.get('format_version')!r}, "
            f"this walkcap reads {FORMAT_VERSION}"
        )
    if meta.get("classes") != list(MODES):
        raise InferenceError(
            f"model {path} classifies {meta.get('classes')!r}, walkcap needs {list(MODES)}"
        )
    if meta.get("input_size") != [INPUT_SIZE, INPUT_SIZE]:
        raise InferenceError(
            f"model {path} takes {meta.get('input_size')!r} images, "
            f"walkcap's preprocessing makes {INPUT_SIZE} x {INPUT_SIZE}"
        )
    architecture = meta.get("architecture")
    hidden = architecture.get("hidden") if isinstance(architecture, dict) else None
    # bool is an int to Python; a huge layer would take the machine's memory
    if isinstance(hidden, bool) or not isinstance(hidden, int) or not 1 <= hidden <= HIDDEN_MAX:
        raise InferenceError(
            f"{mpath}: architecture.hidden must be an integer from 1 to {HIDDEN_MAX}"
        )
    return meta


def probe_images(size: int = INPUT_SIZE) -> np.ndarray:
    """Images the classifier must answer with finite probabilities: empty, level ground
    ahead, and a step up."""
    empty = np.zeros((size, size), np.uint8)
    ground = empty.copy()
    ground[size // 2 :, :] = 1
    step = ground.copy()
    step[size // 4 : size // 2, size // 2 :] = 1
    return np.stack([empty, ground, step])


def probe(clf: Classifier, weights: str | os.PathLike = "") -> None:
    """Refuse a model whose outputs are not finite (what a diverged training run writes)."""
    probabilities = clf.predict_batch(probe_images(clf.input_size))
    if not np.all(np.isfinite(probabilities)):
        raise InferenceError(
            f"model file {weights or clf.path} gives no finite output on a probe image "
            "(NaN or infinite weights: a diverged training run?)"
        )


def load_classifier(
    path: str | os.PathLike | None = None, device: str = "auto", threads: int | None = None
) -> Classifier:
    """Load a classifier; None or "" loads the bundled model.

    A missing file, a corrupt file (hash, unreadable) or a file that does not fit the
    network or walkcap's classes/input size raises InferenceError with one line.
    `threads` sets torch's intra-op threads for the process (1 gives the steadiest
    single-frame latency when other threads share the CPU).
    """
    weights = Path(path) if path else BUNDLED_PATH
    if weights.suffix == ".json":
        weights = weights.with_suffix(".pt")
    if weights.exists() and not weights.is_file():
        raise InferenceError(f"model file {weights} is not a regular file")
    if not weights.is_file():
        hint = " (the bundled model is missing: reinstall walkcap)" if not path else ""
        raise InferenceError(f"model file not found: {weights}{hint}")
    meta = read_metadata(weights)
    if file_sha256(weights) != meta.get("weights_sha256"):
        raise InferenceError(
            f"model file {weights} is corrupt: its SHA-256 does not match "
            f"{metadata_path(weights).name}"
        )
    try:
        # torch warns about what it reads (pickle protocols) before failing on a file that
        # is no state dict: the one-line error below says all the user needs
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            state = torch.load(weights, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises many types for a bad file
        raise InferenceError(
            f"model file {weights} is corrupt or not a state dict: {type(e).__name__}"
        ) from None
    net = TerrainCNN(hidden=meta["architecture"]["hidden"])
    if not isinstance(state, dict):
        raise InferenceError(f"model file {weights} does not hold a state dict")
    expected = net.state_dict()
    problems = [k for k in expected if k not in state]
    problems += [k for k in state if k not in expected]
    problems += [
        f"{k} {tuple(state[k].shape)} != {tuple(v.shape)}"
        for k, v in expected.items()
        if k in state and hasattr(state[k], "shape") and state[k].shape != v.shape
    ]
    if problems:
        raise InferenceError(
            f"model file {weights} does not match the network: {'; '.join(problems[:3])}"
        )
    net.load_state_dict(state)
    if threads:
        torch.set_num_threads(threads)
    clf = Classifier(net, meta, choose_device(device), str(weights))
    probe(clf, weights)
    log.info("loaded terrain classifier %s (%s)", weights, meta.get("weights_sha256", "")[:12])
    return clf


# ---- benchmark ---------------------------------------------------------------------------
