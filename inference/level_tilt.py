"""The IMU's tilt error in the walking direction, estimated from level ground.

The MTi 1-series' roll and pitch are good to 1.0 deg RMS under dynamic conditions (Xsens
MTi 1-series datasheet, MT0512P), and the error wanders slowly (a degree a minute): over
a trial it is nearly a constant tilt of the leveled cloud, so every fitted slope carries
it. Level ground shows it: the tilt of ground the fused decision calls level is that error
(plus the fit's noise). `update` averages it over frames decided level, a running mean at
first and an exponential one (TAU_S) after, and `correct` takes it off a frame's slope.

It must not hide a real ramp or a mislabelled one: it learns only on frames whose fused
decision is level ground and whose features are level (frozen on ramps, stairs and
transitions), only from tilts a level-ground decision plausibly has (GATE_DEG off the
current estimate), and it is bounded by MAX_DEG (three times the datasheet's RMS).
Pure functions on an immutable state: the pipeline holds one per trial, live and in
replay alike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from devices import clock

TAU_S = 10.0  # exponential memory once warm; the error drifts over minutes, not seconds
WARM_FRAMES = 30  # a running mean over the first frames (2 s at 15 fps): fast start
MAX_DEG = 3.0  # |estimate| bound: 3 x the MTi 1-series' 1.0 deg RMS roll/pitch
GATE_DEG = 4.0  # a level frame this far off the estimate teaches nothing (a missed ramp)


@dataclass(frozen=True)
class TiltEstimate:
    """The estimated tilt error (degrees, positive: level ground fits uphill), the frames
    it learned from, and the time of the last (ns)."""

    offset_deg: float = 0.0
    frames: int = 0
    time_ns: int | None = None


def update(
    state: TiltEstimate,
    decision: str | None,
    kind: str | None,
    slope_deg: float | None,
    time_ns: int,
) -> TiltEstimate:
    """The estimate after one frame: `decision` the fused mode ("LG", ...), `kind` and
    `slope_deg` the frame's terrain features (before any correction)."""
    if (
        decision != "LG"
        or kind != "level"
        or slope_deg is None
        or not math.isfinite(slope_deg)
        or abs(slope_deg - state.offset_deg) > GATE_DEG
    ):
        return state  # frozen off level ground
    if state.frames < WARM_FRAMES or state.time_ns is None:
        weight = 1.0 / (state.frames + 1)
    else:
        dt_s = max(0.0, clock.seconds(time_ns - state.time_ns))
        weight = 1.0 - math.exp(-dt_s / TAU_S)
    offset = state.offset_deg + weight * (slope_deg - state.offset_deg)
    offset = min(MAX_DEG, max(-MAX_DEG, offset))
    return TiltEstimate(offset, state.frames + 1, time_ns)


def correct(state: TiltEstimate, slope_deg: float | None) -> float | None:
    """A fitted slope with the estimated tilt error taken off (None stays None)."""
    if slope_deg is None:
        return None
    return slope_deg - state.offset_deg
