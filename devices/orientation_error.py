"""Synthetic IMU orientation error: the one model every simulated orientation goes through.

An attitude filter's output is off by a bias that holds over a session (roll and pitch,
the axes gravity corrects, so they stay bounded) and by noise on every sample. Both act in
the world frame, as a filter's drifting estimate of "down" does: q_measured = n * b * q.
The synthesized training sessions, the synthesized recordings and the IMU emulator draw
their error here, so the classifier trains on the error it meets.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from devices.rotations import quat_from_euler, quat_multiply

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


@dataclass(frozen=True)
class OrientationErrorModel:
    """Sizes of the error, degrees, one sigma per axis."""

    noise_deg: float = 0.7  # on every sample, independent
    bias_deg: float = 0.5  # roll and pitch, drawn once per session


class OrientationError:
    """One session's orientation error, drawn from `rng` (the bias now, noise per sample)."""

    def __init__(self, model: OrientationErrorModel, rng: np.random.Generator) -> None:
        self.model = model
        self._rng = rng
        if model.bias_deg > 0:
            roll, pitch = np.radians(rng.normal(0.0, model.bias_deg, 2))
            self.bias = quat_from_euler(roll, pitch, 0.0)
        else:  # nothing to draw: the rng's stream stays that of a model without bias
            self.bias = IDENTITY

    def apply(self, quaternion: np.ndarray) -> np.ndarray:
        """The measured orientation for a true one ([w, x, y, z], sensor -> world)."""
        error = self.bias
        if self.model.noise_deg > 0:
            roll, pitch, yaw = np.radians(self._rng.normal(0.0, self.model.noise_deg, 3))
            noise = quat_from_euler(roll, pitch, yaw)
            error = quat_multiply(noise, error) if self.model.bias_deg > 0 else noise
        elif self.model.bias_deg <= 0:
            return np.asarray(quaternion, dtype=np.float64)
        return quat_multiply(error, quaternion)
