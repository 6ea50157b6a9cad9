"""Evaluation trials with simulated CNN scores, for the evaluation, fusion and eval tests."""

import numpy as np

from devices.frames import MODES
from inference.evaluation.trials import Trial
from inference.fusion import N_MODES


def synthetic_trial(
    seed: int = 0,
    accuracy: float = 0.9,
    block_frames: tuple[int, int] = (30, 80),
    path: str = "",
    metadata: dict | None = None,
) -> Trial:
    """The paper's course (three level-ground blocks, stairs and ramps up and down) and
    CNN-like scores that pick the true mode on about `accuracy` of the frames, errors
    independent and less confident."""
    rng = np.random.default_rng(seed)
    course = ["LG", "US", "LG", "UR", "LG", "DS", "DR"]
    reference = np.concatenate(
        [np.full(rng.integers(*block_frames), MODES.index(m)) for m in course]
    )
    n = len(reference)
    chosen = reference.copy()
    wrong = rng.random(n) > accuracy
    chosen[wrong] = (reference[wrong] + rng.integers(1, N_MODES, wrong.sum())) % N_MODES
    confidence = np.where(wrong, rng.uniform(0.35, 0.7, n), rng.uniform(0.55, 0.99, n))
    rest = rng.dirichlet(np.ones(N_MODES - 1), n) * (1 - confidence)[:, None]
    probabilities = np.empty((n, N_MODES))
    for i in range(n):
        probabilities[i, chosen[i]] = confidence[i]
        probabilities[i, np.arange(N_MODES) != chosen[i]] = rest[i]
    return Trial(path or f"synthetic-{seed}", probabilities, reference, dict(metadata or {}))


def live_final(fusion, probabilities):
    """What a live session sees: push per frame, flush at the end, final decisions
    (-1: undecided)."""
    n = len(probabilities)
    final = np.full(n, -1)
    for out in [fusion.push(row) for row in probabilities] + fusion.flush():
        if out is None:
            continue
        frame, decision = (
            (out.voted_frame, out.voted) if fusion.votes else (out.frame, out.decision)
        )
        if frame is not None:
            final[frame] = decision
    return final
