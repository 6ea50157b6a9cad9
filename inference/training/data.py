"""What training sees: the split by session, the frames stacked, each epoch's draw (class
balancing) and its batches, augmented and with mirrored ascents (the package docstring
says why)."""

from __future__ import annotations

import math

import numpy as np
import torch

from devices.frames import MODES
from inference.dataset import LabeledSession
from inference.errors import InferenceError
from inference.model import images_to_tensor


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
    if rng.random() < 0.3:
        # The stray returns under a surface missing: the authors' shift registers the image
        # on its lowest point, a stray's or the surface's, so the surface's own rows vary.
        keep &= z >= np.quantile(z, rng.uniform(0.0, 0.1))
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


# ---- epochs and batches ------------------------------------------------------------------


def stack_labelled(sessions: list[LabeledSession]) -> tuple[np.ndarray, np.ndarray]:
    """The sessions' labelled frames, as one array of images and one of labels."""
    parts = [s.labelled() for s in sessions]
    parts = [p for p in parts if len(p)]
    if not parts:
        return np.zeros((0, 100, 100), np.uint8), np.zeros(0, np.int64)
    return (
        np.concatenate([p.images for p in parts]),
        np.concatenate([p.labels for p in parts]).astype(np.int64),
    )


def epoch_indices(
    labels: np.ndarray, count: int, balance: bool, rng: np.random.Generator, power: float = 1.0
) -> np.ndarray:
    """The frames of one epoch, `count` of them: balanced, drawn with probability class
    frequency ** -power (with replacement); else shuffled (drawn when there are fewer)."""
    if not balance or power == 0:
        return (
            rng.permutation(len(labels))[:count]
            if count <= len(labels)
            else rng.integers(0, len(labels), count)
        )
    freq = np.bincount(labels, minlength=len(MODES)).astype(np.float64)
    weights = freq[labels] ** -power
    return rng.choice(len(labels), size=count, replace=True, p=weights / weights.sum())


def batches(
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
