"""Synthetic IMU orientation error: the one model every simulated orientation goes through.

The Xsens MTi 1-series datasheet gives roll/pitch accuracy of 1.0 deg RMS and yaw of 2 deg
RMS under dynamic conditions. An attitude filter's error is not independent per sample:
gravity bounds roll and pitch, the gyros carry them between corrections, so the estimate of
"down" wanders slowly (Xsens: with aiding lost, "a degree every minute"). The model is a
first-order Gauss-Markov process per axis (roll, pitch, yaw),

    x(t + dt) = exp(-dt / tau) x(t) + sigma sqrt(1 - exp(-2 dt / tau)) n,   n ~ N(0, 1),

started from its stationary distribution N(0, sigma^2), plus a small white part per sample
(the legacy MTi's 0.05 deg angular resolution). No Xsens source gives the correlation time;
tau = 120 s is the one at which a 1 deg RMS error changes by about a degree a minute
(sigma sqrt(2 * 60 s / tau)), the rate Xsens quotes. The error acts in the world frame, as
a filter's drifting estimate of "down" does: q_measured = e(t) * q.

The synthesized training sessions, the synthesized recordings and the IMU emulator draw
their error here, so the classifier trains on the error it meets.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from devices.rotations import quat_from_euler, quat_multiply


@dataclass(frozen=True)
class OrientationErrorModel:
    """Sizes of the error, degrees (one sigma per axis), and its correlation time."""

    roll_pitch_deg: float = 1.0  # MTi 1-series, dynamic, RMS
    yaw_deg: float = 2.0  # MTi-3 AHRS, dynamic, RMS
    tau_s: float = 120.0  # Gauss-Markov correlation time
    white_deg: float = 0.05  # independent per sample

    def __post_init__(self) -> None:
        if min(self.roll_pitch_deg, self.yaw_deg, self.white_deg) < 0 or self.tau_s <= 0:
            raise ValueError("orientation error: sizes must be >= 0 and tau_s > 0")

    @property
    def rms_deg(self) -> tuple[float, float, float]:
        """Steady-state RMS of roll, pitch and yaw (drift and white part together)."""
        rp = math.hypot(self.roll_pitch_deg, self.white_deg)
        return rp, rp, math.hypot(self.yaw_deg, self.white_deg)


NO_ERROR = OrientationErrorModel(0.0, 0.0, 1.0, 0.0)


class OrientationError:
    """One session's orientation error, drawn from `rng`; `apply` takes samples in time
    order (a time earlier than the last one restarts nothing: the state just holds)."""

    def __init__(self, model: OrientationErrorModel, rng: np.random.Generator) -> None:
        self.model = model
        self._rng = rng
        self._sigma = np.radians([model.roll_pitch_deg, model.roll_pitch_deg, model.yaw_deg])
        self._white = math.radians(model.white_deg)
        self.state = self._sigma * rng.standard_normal(3)  # roll, pitch, yaw (rad)
        self._t: float | None = None

    def error_at(self, t_s: float) -> np.ndarray:
        """The drift state (roll, pitch, yaw in radians) advanced to t_s."""
        if self._t is not None and t_s > self._t:
            a = math.exp(-(t_s - self._t) / self.model.tau_s)
            kick = self._sigma * math.sqrt(max(0.0, 1.0 - a * a))
            self.state = a * self.state + kick * self._rng.standard_normal(3)
        if self._t is None or t_s > self._t:
            self._t = t_s
        return self.state

    def apply(self, quaternion: np.ndarray, t_s: float) -> np.ndarray:
        """The measured orientation at t_s for a true one ([w, x, y, z], sensor -> world)."""
        angles = self.error_at(t_s)
        if self._white > 0:
            angles = angles + self._white * self._rng.standard_normal(3)
        if not np.any(angles):
            return np.asarray(quaternion, dtype=np.float64)
        return quat_multiply(quat_from_euler(*angles), quaternion)
