"""Textbook images: the five terrains as the authors' recipe draws them, a check of the model.

The recipe (Zhang et al., IEEE TNSRE 2019): level ground is a plane
with +-1 cm noise; ramps are planes at 15 +- 5 degrees up or down; stairs are four treads
with risers of 0.15 +- 0.05 m and treads of 0.33 +- 0.05 m, the first riser 0.2 m ahead.
Each surface is sampled every 2 mm along the sagittal profile (x forward, z up), every
point moved by uniform noise of +-1 cm across its surface, and rasterised as a live frame
is (inference.preprocess.rasterise). Risers are drawn whole, up or down: the recipe's
stairs, not what a camera above a descent sees.

The set is a pure function of its seed and never written as a session, so training never
sees it; `walkcap eval model --textbook` scores a model on it per class.
"""

from __future__ import annotations

import numpy as np

from devices.frames import MODES
from inference.preprocess import rasterise

TEXTBOOK_SEED = 2019
PER_CLASS = 100
NOISE_M = 0.01  # +- 1 cm, uniform
STEP_M = 0.002  # sampling along the profile
LENGTH_M = 1.5  # profile length: more than the image's 0.99 m
SLOPE_DEG = (10.0, 20.0)  # 15 +- 5
RISER_M = (0.10, 0.20)  # 0.15 +- 0.05
TREAD_M = (0.28, 0.38)  # 0.33 +- 0.05
FIRST_RISER_M = 0.2
TREADS = 4


def _line(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    n = max(2, int(np.ceil(np.hypot(*(b - a)) / STEP_M)) + 1)
    return a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)


def textbook_profile(mode: str, rng: np.random.Generator) -> np.ndarray:
    """One terrain's sagittal points (n, 2): x forward, z up, metres."""
    normals: list[np.ndarray] = []
    parts: list[np.ndarray] = []

    def add(a, b, normal):
        pts = _line(np.asarray(a, float), np.asarray(b, float))
        parts.append(pts)
        normals.append(np.broadcast_to(np.asarray(normal, float), pts.shape))

    if mode == "LG":
        add((0.0, 0.0), (LENGTH_M, 0.0), (0.0, 1.0))
    elif mode in ("UR", "DR"):
        slope = np.radians(rng.uniform(*SLOPE_DEG)) * (1 if mode == "UR" else -1)
        add((0.0, 0.0), (LENGTH_M, LENGTH_M * np.tan(slope)), (-np.sin(slope), np.cos(slope)))
    elif mode in ("US", "DS"):
        sign = 1.0 if mode == "US" else -1.0
        riser, tread = rng.uniform(*RISER_M), rng.uniform(*TREAD_M)
        x, z = 0.0, 0.0
        add((x, z), (FIRST_RISER_M, z), (0.0, 1.0))
        x = FIRST_RISER_M
        for _ in range(TREADS):
            add((x, z), (x, z + sign * riser), (1.0, 0.0))
            z += sign * riser
            add((x, z), (x + tread, z), (0.0, 1.0))
            x += tread
    else:
        raise ValueError(f"unknown mode {mode!r}")
    points, normal = np.concatenate(parts), np.concatenate(normals)
    return points + normal * rng.uniform(-NOISE_M, NOISE_M, (len(points), 1))


def textbook_set(
    per_class: int = PER_CLASS, seed: int = TEXTBOOK_SEED
) -> tuple[np.ndarray, np.ndarray]:
    """(images (n, 100, 100) uint8 0/1, labels (n,) mode indices), per_class of each mode."""
    rng = np.random.default_rng([seed, 27])
    images, labels = [], []
    for label, mode in enumerate(MODES):
        for _ in range(per_class):
            image, _ = rasterise(textbook_profile(mode, rng).astype(np.float32))
            images.append(image)
            labels.append(label)
    return np.stack(images), np.array(labels, np.int64)
