"""Labelled sessions of simple drawn terrain profiles, one class each (no simulator): training
and corpus tests run on them in seconds."""

import numpy as np

from devices.frames import MODES
from inference.dataset import LabeledSession


def draw_profile(mode: str, rng: np.random.Generator, grid: int = 100) -> np.ndarray:
    """A binary side view of the terrain ahead, as inference.preprocess draws it."""
    x = np.arange(0, 95, 0.5)
    if mode == "LG":
        z = rng.normal(0, 0.4, len(x))
    elif mode in ("UR", "DR"):
        z = x * np.tan(np.radians(rng.uniform(10, 20))) * (1 if mode == "UR" else -1)
    else:
        start, riser, tread = rng.uniform(10, 30), rng.uniform(10, 20), rng.uniform(25, 35)
        steps = np.floor(np.maximum(x - start, -1) / tread) + 1
        z = steps * riser * (1 if mode == "US" else -1)
    keep = rng.random(len(x)) > 0.1
    x, z = x[keep], z[keep] + rng.normal(0, 0.3, keep.sum())
    col = (x - x.min()).astype(int) + 1
    up = (z - z.min()).astype(int) + 1
    ok = (col < grid) & (up < grid)
    image = np.zeros((grid, grid), np.uint8)
    image[grid - 1 - up[ok], col[ok]] = 1
    return image


def drawn_session(
    name: str, preset: str, seed: int, per_class: int = 8, counts: dict | None = None
) -> LabeledSession:
    rng = np.random.default_rng(seed)
    images, labels = [], []
    for i, mode in enumerate(MODES):
        for _ in range((counts or {}).get(mode, per_class)):
            images.append(draw_profile(mode, rng))
            labels.append(i)
    return LabeledSession(
        name, np.array(images), np.array(labels), preset=preset, flags=np.array([""] * len(labels))
    )


def drawn_sessions(count: int = 6, per_class: int = 8) -> list[LabeledSession]:
    return [
        drawn_session(
            f"{'indoor' if i % 2 == 0 else 'outdoor'}-{i:06d}",
            "indoor" if i % 2 == 0 else "outdoor",
            i,
            per_class,
        )
        for i in range(count)
    ]
