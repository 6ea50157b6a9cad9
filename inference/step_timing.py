"""When the instrumented leg's next step lands on the terrain ahead: the step clock from the
thigh IMU's gait events, and the distance to the next terrain from the terrain features'
edges, followed as the walker closes in (inference.fusion_steps times its changes by them).

A prosthesis needs the new mode at the heel contact of the first step on the new terrain
and the old one at the heel contact before. The camera sees the change one or two strides
ahead; which heel contact is the first on the new terrain follows from where the terrain
changes (an edge of inference.features, seen from the camera) and where the hip will be at
the next step's mid-stance (the foot under the hip: the step's terrain). The edge is fixed
in the world and the walker closes in on it, so its distances from the hip over the last
frames lie on a line whose slope is the walking speed: a tracker that follows that line
and leaves out what lies off it (a later riser, an edge the noise moved, an object in
view) gives both.

Pure: the fusion feeds the events and the frames in, as the live pipeline and eval do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from inference.fusion_design import (
    STEP_CAMERA_FORWARD_M,
    STEP_SPEED_MPS,
    STEP_SPEEDS,
    STEP_SWING_SHARE,
    STEP_THIGH_M,
    STEP_TRACK_ALPHA,
    STEP_TRACK_BETA,
    STEP_TRACK_INLIER_M,
    STEP_TRACK_MIN_POINTS,
    STEP_TRACK_MIN_SPAN_S,
    STEP_TRACK_MISSES,
    STEP_TRACK_S,
)

HEEL_CONTACT, TOE_OFF = "heel_contact", "toe_off"  # devices.frames.GAIT_EVENTS
_RATE = 0.3  # the running means of the stride and the swing: about the last 3 strides


def hip_offset_m(flexion_deg: float) -> float:
    """How far ahead of the hip the camera is, horizontally, at a thigh flexion (degrees,
    positive lifting the knee): it sits STEP_THIGH_M down the thigh from the hip and
    STEP_CAMERA_FORWARD_M in front of it."""
    f = math.radians(flexion_deg)
    return STEP_THIGH_M * math.sin(f) + STEP_CAMERA_FORWARD_M * math.cos(f)


@dataclass(frozen=True)
class EdgeFit:
    """An edge followed over frames: its distance ahead of the hip at `time_s`, the walking
    speed that closes it, and how many of the measurements agree."""

    distance_m: float
    speed_mps: float
    inliers: int


class EdgeTrack:
    """One kind of edge followed over the frames: its distance ahead of the hip and the
    speed that closes it, an alpha-beta tracker (a constant-speed Kalman filter with fixed
    gains) on its hip-relative distances. A measurement farther than STEP_TRACK_INLIER_M
    from the prediction is another edge (a later riser, an edge the noise moved, an object
    in view) and is left out; STEP_TRACK_MISSES of them in a row start the track again
    there (the edge followed went out of view, the next one is the edge now). O(1) a frame."""

    def __init__(self, span_s: float = STEP_TRACK_S) -> None:
        self.span_s = span_s
        self.clear()

    def clear(self) -> None:
        self._time: float | None = None  # of the estimate
        self._distance = 0.0
        self._speed: float | None = None
        self._first: tuple[float, float] | None = None  # a lone measurement, not yet a track
        self._agreed = 0  # measurements the track took in
        self._misses = 0  # left out in a row
        self._last: tuple[float, float] | None = None

    def add(self, time_s: float, distance_m: float, speed_mps: float | None = None) -> None:
        """A measurement; `speed_mps`: the walking speed to start a track with when its
        first two measurements are too close in time to tell (STEP_TRACK_MIN_SPAN_S)."""
        self._last = (time_s, distance_m)
        if self._time is not None and time_s - self._time > self.span_s:
            self.clear()
            self._last = (time_s, distance_m)
        if self._time is None:
            first = self._first
            if first is None or time_s - first[0] > self.span_s:
                self._first = (time_s, distance_m)
                return
            dt = time_s - first[0]
            if dt < STEP_TRACK_MIN_SPAN_S:
                if speed_mps is None:
                    return
                speed = speed_mps
            else:
                speed = (first[1] - distance_m) / dt
            self._time, self._distance = time_s, distance_m
            self._speed = min(max(speed, STEP_SPEEDS[0]), STEP_SPEEDS[1])
            self._agreed, self._misses = 2, 0
            return
        dt = time_s - self._time
        predicted = self._distance - self._speed * dt
        residual = distance_m - predicted
        if abs(residual) > STEP_TRACK_INLIER_M:
            self._misses += 1
            if self._misses >= STEP_TRACK_MISSES:  # the edge is another one now
                speed = self._speed
                self.clear()
                self._first = (time_s, distance_m)
                self._last = (time_s, distance_m)
                self.add(time_s, distance_m, speed)
            return
        self._misses = 0
        self._agreed += 1
        self._time, self._distance = time_s, predicted + STEP_TRACK_ALPHA * residual
        if dt > 0:
            speed = self._speed - STEP_TRACK_BETA * residual / dt
            self._speed = min(max(speed, STEP_SPEEDS[0]), STEP_SPEEDS[1])

    def forget(self, now_s: float) -> None:
        if self._last is not None and now_s - self._last[0] > self.span_s:
            self.clear()

    def last(self) -> tuple[float, float] | None:
        """The newest measurement (time, distance), taken in or not."""
        return self._last

    def fit(self, now_s: float) -> EdgeFit | None:
        """The edge's distance at `now_s` and the walking speed, once STEP_TRACK_MIN_POINTS
        measurements agree; None before."""
        if self._time is None or self._agreed < STEP_TRACK_MIN_POINTS:
            return None
        speed = self._speed
        return EdgeFit(self._distance - speed * (now_s - self._time), speed, self._agreed)


class StepClock:
    """The instrumented leg's step rhythm from the detector's events: when its next heel
    contact comes, the stride, whether it walks."""

    def __init__(self, stride_s: float, stall_s: float) -> None:
        self.stride_s = stride_s
        self.stall_s = stall_s
        self.swing = STEP_SWING_SHARE  # of a stride, toe off to heel contact
        self.heel_contact_s: float | None = None
        self.toe_off_s: float | None = None

    def see(self, event: str, time_s: float) -> None:
        if event == HEEL_CONTACT:
            last = self.heel_contact_s
            if last is not None and 0 < time_s - last < self.stall_s:
                stride = time_s - last
                off = self.toe_off_s
                if off is not None and last < off < time_s:
                    self.swing += ((time_s - off) / stride - self.swing) * _RATE
                self.stride_s += (stride - self.stride_s) * _RATE
            self.heel_contact_s = time_s
        elif event == TOE_OFF:
            self.toe_off_s = time_s

    def walking(self, now_s: float) -> bool:
        return self.heel_contact_s is not None and now_s - self.heel_contact_s < self.stall_s

    def next_heel_contact(self, now_s: float) -> float:
        """When the next heel contact comes: a swing after the last toe off while the foot
        swings, a stride after the last heel contact otherwise; `now_s` when that is past
        (it lands any moment: the detector reports a heel contact within a few
        hundredths of a second)."""
        last, off = self.heel_contact_s, self.toe_off_s
        if last is None:
            return now_s
        if off is not None and off > last:
            due = off + self.swing * self.stride_s
        else:
            due = last + self.stride_s
        return max(due, now_s)


def speed_or(fit: EdgeFit | None, last_speed: float | None) -> float:
    """The walking speed to extrapolate with: the fit's, else the last one fitted, else a
    walker's usual STEP_SPEED_MPS."""
    if fit is not None:
        return fit.speed_mps
    return last_speed if last_speed is not None else STEP_SPEED_MPS
